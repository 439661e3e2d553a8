"""A path tracer whose rays stay on the refracted path: Mitsuba's ``path`` with one change.

Mitsuba starts every new ray of a path at ``p + (1 + max|p_i|)·ε·n`` (``ε`` = 8.94e-5 in
single precision, ``n`` the surface normal on the side the ray leaves to): a clearance against
self-intersection along the *normal*. After a refraction the ray's direction is oblique, so this
start point is off the refracted ray by ``(1 + max|p_i|)·ε·tan θ`` sideways — towards the axis,
at every interface. At a port 100–230 mm from the origin of the scene that is 0.009–0.021 mm per
interface, and everything behind the port images 2–3e-5 too far from the image centre (0.01–0.035
px on the paper's scene; measured and explained in docs/architecture.md). The forward model has
no such offset; a benchmark should not either.

:class:`RefractedPathIntegrator` (plugin name ``refracted_path``) starts each new ray *on* the
sampled direction, at ``p + (c / |cos θ|)·d`` with the same normal clearance ``c``, so that the
ray leaves the surface exactly as Mitsuba's does but without the sideways step. Everything else is
unidirectional path tracing with BSDF sampling, as the ``path`` integrator does for the scenes of
this project (emitting targets, dielectric interfaces, black backs: emitter sampling cannot
contribute through delta BSDFs). Scene files keep ``<integrator type="path">`` so that they
load in any Mitsuba; :mod:`synth.render` substitutes this integrator with the same
``max_depth``.
"""

from __future__ import annotations

import re

#: Name under which the integrator is registered with Mitsuba.
PLUGIN_NAME = "refracted_path"
#: Renderer revision in the request keys of datasets and boards folders: outputs rendered before
#: this integrator existed are not taken for current ones.
RENDERER = PLUGIN_NAME
#: Smallest ``|cos θ|`` the clearance is divided by (grazing rays start at most 10 clearances
#: along their direction).
MIN_COS = 0.1

_registered_for: set = set()
mi = dr = None  # the Mitsuba and Dr.Jit modules, set by register()


def register(mitsuba) -> None:
    """Register :data:`PLUGIN_NAME` with the Mitsuba module of the current variant."""
    global mi, dr
    variant = mitsuba.variant()
    if variant in _registered_for:
        return
    import drjit

    # @dr.syntax recompiles ``sample`` with this module's globals (not the closure): the
    # modules it uses are globals.
    mi, dr = mitsuba, drjit

    class RefractedPathIntegrator(mi.SamplingIntegrator):
        """See the module docs; ``max_depth`` as Mitsuba's ``path`` (−1: unlimited)."""

        def __init__(self, props):
            super().__init__(props)
            depth = props.get("max_depth", 8)
            self.max_depth = (1 << 31) - 1 if depth < 0 else int(depth)

        @dr.syntax
        def sample(self, scene, sampler, ray, medium=None, active=True):
            ctx = mi.BSDFContext()
            ray = mi.Ray3f(ray)
            radiance = mi.Spectrum(0.0)
            throughput = mi.Spectrum(1.0)
            depth = mi.UInt32(0)
            active = mi.Bool(active)
            while dr.hint(active, max_iterations=self.max_depth, label="refracted_path"):
                si = scene.ray_intersect(ray, ray_flags=mi.RayFlags.All, coherent=depth == 0,
                                         active=active)
                radiance += throughput * si.emitter(scene).eval(si, active)
                active &= si.is_valid() & (depth + 1 < self.max_depth)
                bsdf = si.bsdf(ray)
                sample, weight = bsdf.sample(ctx, si, sampler.next_1d(active),
                                             sampler.next_2d(active), active)
                throughput *= weight
                active &= dr.max(mi.unpolarized_spectrum(throughput)) > 0
                direction = si.to_world(sample.wo)
                clearance = (1.0 + dr.max(dr.abs(si.p))) * mi.math.RayEpsilon
                cos_out = dr.maximum(dr.abs(dr.dot(si.n, direction)), MIN_COS)
                ray = mi.Ray3f(dr.fma(direction, clearance / cos_out, si.p), direction,
                               si.time, si.wavelengths)
                depth += 1
            return radiance, depth != 0, []

        def aov_names(self):
            return []

        def to_string(self):
            return f"RefractedPathIntegrator[max_depth={self.max_depth}]"

    mi.register_integrator(PLUGIN_NAME, lambda props: RefractedPathIntegrator(props))
    _registered_for.add(variant)


def render_integrator(mitsuba, scene):
    """The integrator to render ``scene`` with: this one in place of Mitsuba's ``path`` (same
    ``max_depth``), ``None`` (the scene's own) for any other integrator."""
    described = str(scene.integrator())
    if not described.startswith("PathIntegrator"):
        return None
    match = re.search(r"max_depth\s*=\s*(-?\d+)", described)
    register(mitsuba)
    return mitsuba.load_dict({"type": PLUGIN_NAME,
                              "max_depth": int(match.group(1)) if match else 8})


def integrator_name(mitsuba, scene) -> str:
    """The plugin name :func:`render_integrator` renders ``scene`` with (for manifests)."""
    if render_integrator(mitsuba, scene) is not None:
        return PLUGIN_NAME
    return str(scene.integrator()).split("[", 1)[0]
