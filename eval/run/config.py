"""The one typed configuration of a run of ``python -m eval run``.

:class:`RunConfig` is frozen and complete: what to measure (the scene, its ``-D`` values, the
seed, a ``--from`` dataset, the render's samples and variant), what the measurement believes
(``--assume``, ``--calib``, ``--compare-calib``) and how it measures (methods, noise, gate, depth
range, detection options, eccentricity, self-calibration, sensor). The command line builds it
with :meth:`RunConfig.from_args`; ``eval sweep`` builds it directly from a cell's parameters.
The target pipeline (:mod:`eval.run.pipeline`) and the dense pipeline (:mod:`eval.run.dense`)
both read it.

Units: millimetres and pixels, as the field names say.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from eval.cli import CLIError
from eval.core.detection import fraction

#: Triangulation methods of a target run when ``--methods`` is not given.
DEFAULT_METHODS = ("optical_path", "su", "regular")
COMMAND = "eval run"


@dataclass(frozen=True)
class RunConfig:
    """Everything a run needs to know, checked (see the module docs).

    ``defines``: the ``-D`` values as ``(name, value text)`` pairs; ``seed``: the run's one
    seed (None: the scene's); ``assumptions``: ``{name: numpy array}`` of ``--assume``
    (:func:`eval.core.assumption.parse_assumptions`); ``methods``: None for the default of
    the scene's kind (targets: :data:`DEFAULT_METHODS`; surfaces: both dense methods);
    ``depth_range_mm``: ``(near, far)`` along the port normal or None for the default;
    ``sensor``: a :class:`synth.rendering.sensor_model.SensorModel` or None; ``assumption_notes``: how
    an assumed value was computed (``n_water`` from temperature and salinity), to show once;
    ``no_figures``: write the report and point clouds without the PNG figures."""

    scene: str
    defines: tuple = ()
    seed: int | None = None
    from_dir: str | None = None
    spp: int | None = None
    variant: str | None = None
    full_film: bool = False
    assumptions: dict = field(default_factory=dict)
    calib: str | None = None
    compare_calib: tuple = ()
    absorbed_calib: str | None = None
    methods: tuple | None = None
    noise_px: float = 0.0
    gate_mm: float = 0.5
    depth_range_mm: tuple | None = None
    self_calibrate: tuple = ()
    eccentricity: bool | None = None
    threshold_fraction: float | None = None
    max_elongation: float | None = None
    max_area_ratio: float | None = None
    median_filter: int = 0
    sensor: object = None
    progress: bool = True
    assumption_notes: tuple = ()
    pixel_sigma: object = "auto"
    no_figures: bool = False

    def target_methods(self) -> tuple:
        """The triangulation methods of a target run; CLIError names an unknown one."""
        from measure import METHODS

        from eval.core.absorbed import ABSORBED

        if self.methods is None:
            return DEFAULT_METHODS
        known = METHODS + (ABSORBED,)
        unknown = [m for m in self.methods if m not in known]
        if not self.methods or unknown:
            raise CLIError(f"unknown method {', '.join(unknown) or repr(','.join(self.methods))} "
                           f"in --methods (choose from {', '.join(known)})")
        return self.methods

    @property
    def port_methods(self) -> tuple:
        """The target methods that use the port model (all but ``absorbed``): the stages
        that change the port's rig (self-calibration, the error budget) or correct pixels with
        it (eccentricity) run these."""
        from eval.core.absorbed import ABSORBED

        return tuple(m for m in self.target_methods() if m != ABSORBED)

    @property
    def corrects_eccentricity(self) -> bool:
        """Whether a target run corrects the disk targets' eccentricity (``--eccentricity``,
        the default; ``--no-eccentricity`` measures the raw centroids only)."""
        return True if self.eccentricity is None else bool(self.eccentricity)

    @property
    def absorbed(self) -> bool:
        """Whether the run measures with the absorbed baseline (``--methods …,absorbed``)."""
        from eval.core.absorbed import ABSORBED

        return self.methods is not None and ABSORBED in self.methods

    @property
    def rig_source(self) -> str:
        """Where the measurement's rig comes from, in words (for the report)."""
        return (f"--calib {self.calib}" if self.calib else "the scene's rig") + (
            " with --assume" if self.assumptions else "")

    @classmethod
    def from_args(cls, args) -> RunConfig:
        """The configuration of the parsed command line ``args``; CLIError (or ValueError)
        names the bad option — before any expensive work."""
        from synth.scene import parse_defines

        from eval.core.assumption import parse_assumptions
        from eval.core.uncertainty import parse_pixel_sigma

        notes = []
        config = cls(scene=args.scene, defines=tuple(parse_defines(args.defines).items()),
                   seed=args.seed, from_dir=args.from_dir, spp=args.spp, variant=args.variant,
                   full_film=args.full_film,
                   assumptions=parse_assumptions(args.assume, notes), calib=args.calib,
                   compare_calib=tuple(args.compare_calib),
                   absorbed_calib=getattr(args, "absorbed_calib", None),
                   methods=None if args.methods is None else split_names(args.methods),
                   noise_px=args.noise_px, gate_mm=args.gate_mm,
                   depth_range_mm=parse_depth_range(args.depth_range),
                   self_calibrate=parse_self_calibration(args.self_calibrate),
                   eccentricity=args.eccentricity, threshold_fraction=args.threshold_fraction,
                   max_elongation=args.max_elongation, max_area_ratio=args.max_area_ratio,
                   median_filter=args.median_filter, sensor=parse_sensor(args.sensor),
                   progress=not args.no_progress, assumption_notes=tuple(notes),
                   pixel_sigma=parse_pixel_sigma(getattr(args, "pixel_sigma", "auto")),
                   no_figures=getattr(args, "no_figures", False))
        config.refuse_inapplicable()
        return config

    def refuse_inapplicable(self) -> None:
        """CLIError for an option that cannot apply (refused, never ignored): ``--spp`` and
        ``--variant`` with ``--from`` (the dataset's images are reused as rendered; ``-D spp``
        is compared with what they were rendered with); ``--absorbed-calib`` without the
        ``absorbed`` method."""
        if self.absorbed_calib and not self.absorbed:
            raise CLIError(f"--absorbed-calib {self.absorbed_calib} does not apply without the "
                           f"absorbed method: add it to --methods (e.g. "
                           f"--methods optical_path,absorbed)")
        if not self.from_dir:
            return
        for option, value in (("--spp", self.spp), ("--variant", self.variant),
                              ("--full-film", self.full_film or None)):
            if value is not None:
                raise CLIError(f"{option} does not apply with --from {self.from_dir}: its images "
                               f"are reused as they were rendered (-D spp=N checks what they "
                               f"were rendered with)")


def split_names(text: str) -> tuple:
    """A comma list (``--methods``, ``--self-calibrate``) as a tuple of its names, each once,
    in order."""
    return tuple(dict.fromkeys(n.strip() for n in (text or "").split(",") if n.strip()))


def parse_self_calibration(text: str) -> tuple:
    """``--self-calibrate`` (comma list) as a tuple of port parameters."""
    from measure.calibration.selfcal import PARAMETERS

    names = split_names(text)
    unknown = [n for n in names if n not in PARAMETERS]
    if unknown:
        raise CLIError(f"--self-calibrate {text!r}: unknown parameter {', '.join(unknown)} "
                       f"(the refinement estimates {', '.join(PARAMETERS)})")
    return names


def parse_sensor(text):
    """The ``--sensor`` model, or None; CLIError names what is wrong."""
    if text is None:
        return None
    from synth.rendering.sensor_model import SensorError, sensor_from_spec

    try:
        return sensor_from_spec(text)
    except SensorError as exc:
        raise CLIError(f"--sensor {text}: {exc}") from None


def parse_depth_range(text):
    """``--depth-range NEAR,FAR`` (mm) as ``(near, far)``, or None."""
    if text is None:
        return None
    try:
        near, far = (float(v) for v in text.split(","))
    except ValueError:
        raise CLIError(f"--depth-range must be NEAR,FAR in mm, got {text!r}") from None
    if math.isfinite(near) and near < 0:
        raise CLIError(f"--depth-range {text}: the near end must not be negative (NEAR >= 0 mm, "
                       f"the distance along the port normal)")
    if not (math.isfinite(near) and math.isfinite(far) and 0 <= near < far):
        raise CLIError(f"--depth-range must satisfy 0 <= NEAR < FAR (finite), got {text!r}")
    return near, far


__all__ = ["COMMAND", "DEFAULT_METHODS", "RunConfig", "fraction", "parse_depth_range",
           "parse_self_calibration", "parse_sensor", "split_names"]
