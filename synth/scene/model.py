"""What a scene file says, its error type and the defaults it is written with.

Units: millimetres; frame: the reference frame (the left camera's, OpenCV axes: x right, y down,
z forward). :mod:`synth.scene.write` writes scenes, :mod:`synth.scene.read` reads them back into
a :class:`SceneSpec`.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from measure import Camera, Rig

#: Defaults written into every scene unless given. ``spp`` is what a lit pixel gets: target
#: scenes render adaptively (synth.rendering.render), where 144 spp on the lit pixels costs about as much
#: as 36 (the pilot over the whole film dominates) and halves the centroid noise
#: (docs/speed.md, "Adaptive rendering").
DEFAULT_SPP = 144
#: The default of scenes whose film is mostly lit (surfaces, scattering water): rendered on the
#: full film, where the samples cost in proportion.
DEFAULT_FULL_FILM_SPP = 36
DEFAULT_SEED = 0
DEFAULT_MAX_DEPTH = 8
#: Target disk radius, mm: at 1 m behind the paper's port the innermost circle's neighbours
#: (7.6 mm apart, ~10.8 px) keep a ~3.7 px gap, and each disk covers ~40-50 px.
DEFAULT_TARGET_RADIUS_MM = 2.5
#: Prefix of the target shapes' ids.
TARGET_ID_PREFIX = "target_"
#: Id of the surface mesh shape of a dense (surface) scene, and of its speckle texture.
SURFACE_ID, SPECKLE_ID = "surface", "speckle"


@dataclass(frozen=True)
class SurfaceFiles:
    """The files of a surface scene, as the XML names them (relative to the scene file's
    directory): ``mesh`` a PLY of :func:`synth.scene.surfaces.write_ply`, ``texture`` an 8-bit grey
    speckle PNG (linear reflectance, or radiance when self-luminous)."""

    mesh: str
    texture: str


@dataclass(frozen=True)
class SceneSurface:
    """The surface of a scene read back: ``mesh_path`` and ``texture_path`` (resolved),
    ``vertices`` ``(V, 3)`` mm (float32 values widened: what the renderer sees), ``triangles``
    ``(T, 3)``, ``sha256`` of the mesh and texture bytes together."""

    mesh_path: str
    texture_path: str
    vertices: np.ndarray
    triangles: np.ndarray
    sha256: str


class SceneError(ValueError):
    """A scene file that cannot be used: missing, malformed, or not a port/stereo scene."""


@dataclass(frozen=True)
class SceneSpec:
    """What a scene file says, after ``<default>`` values and ``-D`` overrides are applied.

    ``rig`` is a :class:`measure.Rig` of two. In a scene with no port (``has_port`` False) its port
    is an index-matched stand-in: ``FlatPort(N = left optical axis, D = 1 mm beyond the farther
    camera centre, no layers, indices (1, 1))``, through which every projection and triangulation
    reduces to the pinhole one. ``targets`` ``(N, 3)`` ground-truth centres (mm, reference frame)
    in target-number order; ``target_ids`` ``(N,)`` their numbers; ``target_radii`` ``(N,)`` mm;
    ``target_normals`` ``(N, 3)`` the unit normals of the disks (their emitting side);
    ``params`` the resolved ``<default>`` values (strings) ; ``path`` the file; ``sha256`` of its
    bytes.
    """

    rig: Rig
    has_port: bool
    targets: np.ndarray
    target_ids: np.ndarray
    target_radii: np.ndarray
    params: dict
    path: str | None
    sha256: str
    referenced: frozenset = frozenset()
    target_normals: np.ndarray | None = None
    surface: SceneSurface | None = None
    #: The cameras after the first two of a scene of N (``synth scene --cameras N``), all
    #: behind the one flat port (or none) or each behind its own: :attr:`all_cameras`,
    #: :attr:`multirig`.
    extra_cameras: tuple = ()
    #: In a scene of N cameras each behind its own flat port (``--cameras N --port
    #: per-camera``) or inside its own dome (``--cameras N --port dome``): the ports of
    #: :attr:`extra_cameras` (``rig.port`` is then the
    #: :class:`measure.geometry.flat_pair.FlatPair` or the
    #: :class:`measure.geometry.dome.DomePair` of the first two); empty otherwise.
    extra_ports: tuple = ()
    #: In a scene of cameras with different kinds of port (``--port mixed``): every camera's
    #: port, a :class:`synth.scene.mixed.MixedPorts` (None: a camera in air); empty otherwise.
    ports: tuple = ()

    @property
    def mitsuba_params(self) -> dict:
        """The resolved defaults that the XML references as ``$name`` (Mitsuba's loader rejects
        parameters a file does not use), as keyword arguments for ``mi.load_file``."""
        return {k: str(v) for k, v in self.params.items() if k in self.referenced}

    @property
    def cameras(self) -> tuple[Camera, Camera]:
        return self.rig.left, self.rig.right

    @property
    def all_cameras(self) -> tuple:
        """Every camera of the scene, in the order of its sensors."""
        return (self.rig.left, self.rig.right) + tuple(self.extra_cameras)

    def require_two_cameras(self, command: str) -> SceneSpec:
        """This scene, or ValueError (one line naming the scene and ``command``) when it has
        more than two cameras: a command that handles a stereo pair refuses such a scene rather
        than use its first two cameras alone."""
        if self.extra_cameras:
            raise ValueError(f"{self.path}: a scene of {len(self.all_cameras)} cameras; "
                             f"{command} handles two (python -m synth render writes every view, "
                             f"python -m eval run measures them)")
        return self

    @property
    def camera_names(self) -> tuple:
        """``left``, ``right`` — or ``cam0``, ``cam1``, … in a scene of more cameras."""
        from measure.stereo.rig import default_names

        return default_names(len(self.all_cameras))

    @property
    def multirig(self):
        """The scene's rig as a :class:`measure.stereo.rig.Rig` (every camera, each
        with the port it looks through)."""
        from measure.stereo.rig import Rig

        if self.ports:
            return Rig(self.all_cameras, list(self.ports))
        if not self.extra_cameras:
            return Rig.from_stereo(self.rig)
        if self.extra_ports:
            return Rig(self.all_cameras, [self.rig.view_port(0), self.rig.view_port(1),
                                               *self.extra_ports])
        return Rig(self.all_cameras, [self.rig.port] * len(self.all_cameras))

    @property
    def camera_ports(self):
        """What the scene writer takes as the port (:func:`synth.scene.write.scene_xml`): the
        list of every camera's flat port or dome in a scene of N cameras each behind its own,
        else :attr:`port`."""
        if self.ports:
            return self.ports
        if self.extra_ports:
            return list(self.multirig.ports)
        return self.port

    @property
    def port(self):
        """The port — a :class:`measure.FlatPort`, or a :class:`measure.geometry.dome.DomePair` in a dome
        scene (``rig.port.kind == "dome"``) — or None in an all-air scene."""
        return self.rig.port if self.has_port else None

    @property
    def target_radius(self) -> float:
        """The (largest) target radius, mm."""
        return float(np.max(self.target_radii)) if self.target_radii.size else float("nan")

    @property
    def size(self) -> tuple[int, int]:
        return self.rig.left.size

    @property
    def spp(self) -> int:
        return int(float(self.params.get("spp", DEFAULT_SPP)))

    @property
    def seed(self) -> int:
        return int(float(self.params.get("seed", DEFAULT_SEED)))

    def rendered_with(self, spp: int | None = None, seed: int | None = None) -> SceneSpec:
        """This scene with the ``spp`` and ``seed`` it is rendered with recorded in ``params``
        (those it declares), so that the parameters say what was rendered: ``--spp 4`` and
        ``-D spp=4`` give the same parameters. None keeps the scene's own value."""
        values = {name: str(int(value)) for name, value in (("spp", spp), ("seed", seed))
                  if value is not None and name in self.params}
        return replace(self, params={**self.params, **values}) if values else self
