"""A path tracer whose rays stay on the refracted path: Mitsuba's ``path`` with one change.

Mitsuba starts every new ray of a path at ``p + (1 + max|p_i|)·ε·n`` (``ε`` = 8.94e-5 in
single precision, ``n`` the surface normal on the side the ray leaves to): a clearance against
self-intersection along the *normal*. After a refraction the ray's direction is oblique, so this
start point is off the refracted ray by ``(1 + max|p_i|)·ε·tan θ`` sideways — towards the axis,
at every interface. At a port 100–230 mm from the origin of the scene that is 0.009–0.021 mm per
interface, and everything behind the port images 2–3e-5 too far from the image centre (0.01–0.035
px on the paper's scene; measured and explained in docs/architecture.md). The forward model has
no such offset; a benchmark should not either.

:data:`PLUGIN_NAME` (``refracted_path``) starts each new ray *on* the
sampled direction, at ``p + (c / |cos θ|)·d`` with the same normal clearance ``c``, so that the
ray leaves the surface exactly as Mitsuba's does but without the sideways step. Everything else is
unidirectional path tracing with BSDF sampling, as the ``path`` integrator does for the scenes of
this project (emitting targets, dielectric interfaces, black backs: emitter sampling cannot
contribute through delta BSDFs). Scene files keep ``<integrator type="path">`` so that they
load in any Mitsuba; :mod:`synth.rendering.render` substitutes this integrator with the same
``max_depth``.

Scenes with water that absorbs and scatters (``<integrator type="volpath">`` and a homogeneous
medium behind the port, :mod:`synth.rendering.water`) get ``refracted_volpath``: the same ray starts, and
free-flight sampling through Mitsuba's medium, next-event estimation towards the emitters and
Henyey–Greenstein (phase function) sampling at scattering events, Russian roulette after
:data:`RR_DEPTH` events.
"""

from __future__ import annotations

import re

#: Name under which the integrator is registered with Mitsuba.
PLUGIN_NAME = "refracted_path"
#: The same through participating media (in place of Mitsuba's ``volpath``).
VOLUME_PLUGIN_NAME = "refracted_volpath"
#: Renderer revision in the request keys of datasets and boards folders: outputs rendered before
#: this integrator existed are not taken for current ones.
RENDERER = PLUGIN_NAME
#: Events after which ``refracted_volpath`` plays Russian roulette, and its largest survival
#: probability (Mitsuba's ``volpath``: 5 and 0.95).
RR_DEPTH, RR_MAX_Q = 5, 0.95
#: Smallest ``|cos θ|`` the clearance is divided by (grazing rays start at most 10 clearances
#: along their direction).
MIN_COS = 0.1

_registered_for: set = set()
mi = dr = None  # the Mitsuba and Dr.Jit modules, set by register()


def register(mitsuba) -> None:
    """Register :data:`PLUGIN_NAME` and :data:`VOLUME_PLUGIN_NAME` with the Mitsuba module of
    the current variant (classes made here: they subclass the variant's
    ``SamplingIntegrator``)."""
    global mi, dr
    variant = mitsuba.variant()
    if variant in _registered_for:
        return
    import drjit

    # @dr.syntax recompiles ``sample`` with this module's globals (not the closure): the
    # modules it uses are globals.
    mi, dr = mitsuba, drjit
    path = type("RefractedPathIntegrator", (mi.SamplingIntegrator,), {
        "__doc__": "See the module docs; ``max_depth`` as Mitsuba's ``path`` (−1: unlimited).",
        "__init__": _init_with_depth(8), "sample": dr.syntax(_path_sample),
        "aov_names": lambda self: [],
        "to_string": lambda self: f"RefractedPathIntegrator[max_depth={self.max_depth}]"})
    volpath = type("RefractedVolpathIntegrator", (mi.SamplingIntegrator,), {
        "__doc__": _VOLPATH_DOC, "__init__": _init_with_depth(64),
        "sample": dr.syntax(_volpath_sample), "aov_names": lambda self: [],
        "to_string": lambda self: f"RefractedVolpathIntegrator[max_depth={self.max_depth}]"})
    mi.register_integrator(PLUGIN_NAME, lambda props: path(props))
    mi.register_integrator(VOLUME_PLUGIN_NAME, lambda props: volpath(props))
    _registered_for.add(variant)


_VOLPATH_DOC = """``refracted_path`` through participating media: Mitsuba's ``volpath`` with
free-flight distances from the medium, next-event estimation (one emitter sample, homogeneous
transmittance, a shadow ray) and phase function sampling at each scattering event, BSDF sampling
at surfaces, and every surface ray started on its direction. The two estimates of an emitter
seen from a scattering event are combined with the balance heuristic (MIS), as ``volpath`` does.
``max_depth`` counts surface and medium events."""


def _init_with_depth(default_depth: int):
    """An integrator's ``__init__``: ``max_depth`` (default ``default_depth``; −1 unlimited)
    and ``surface_nee`` from the plugin's properties."""
    def init(self, props):
        mi.SamplingIntegrator.__init__(self, props)
        depth = props.get("max_depth", default_depth)
        self.max_depth = (1 << 31) - 1 if depth < 0 else int(depth)
        self.surface_nee = bool(props.get("surface_nee", False))
    return init


def _path_sample(self, scene, sampler, ray, medium=None, active=True):
    """``refracted_path``'s ``sample`` (compiled by ``dr.syntax`` in :func:`register`)."""
    ctx = mi.BSDFContext()
    ray = mi.Ray3f(ray)
    radiance = mi.Spectrum(0.0)
    throughput = mi.Spectrum(1.0)
    depth = mi.UInt32(0)
    active = mi.Bool(active)
    nee = mi.Bool(self.surface_nee)
    after_nee = mi.Bool(False)  # the ray left a surface where an emitter was sampled
    prev_p = mi.Point3f(0.0)  # ... at this point,
    prev_pdf = mi.Float(0.0)  # ... in a direction of this BSDF pdf
    while dr.hint(active, max_iterations=self.max_depth, label="refracted_path"):
        si = scene.ray_intersect(ray, ray_flags=mi.RayFlags.All, coherent=depth == 0,
                                 active=active)
        mis = _hit_weight(scene, si, prev_p, prev_pdf, active & after_nee, self.surface_nee)
        radiance += throughput * mis * si.emitter(scene).eval(si, active)
        active &= si.is_valid() & (depth + 1 < self.max_depth)
        bsdf = si.bsdf(ray)
        smooth = active & nee & mi.has_flag(bsdf.flags(), mi.BSDFFlags.Smooth)
        radiance += throughput * _surface_nee(scene, sampler, ctx, bsdf, si, 0.0, smooth,
                                              self.surface_nee)
        sample, weight = bsdf.sample(ctx, si, sampler.next_1d(active), sampler.next_2d(active),
                                     active)
        throughput *= weight
        active &= dr.max(mi.unpolarized_spectrum(throughput)) > 0
        ray = _surface_ray(si, si.to_world(sample.wo))
        after_nee = smooth & ~mi.has_flag(sample.sampled_type, mi.BSDFFlags.Delta)
        prev_p = dr.select(smooth, si.p, prev_p)
        prev_pdf = dr.select(smooth, sample.pdf, prev_pdf)
        depth += 1
    return radiance, depth != 0, []


def _surface_ray(si, direction):
    """The ray leaving surface point ``si`` along ``direction``, started *on* it: at
    ``p + (c / |cos θ|)·d`` with Mitsuba's normal clearance ``c`` (module docs)."""
    clearance = (1.0 + dr.max(dr.abs(si.p))) * mi.math.RayEpsilon
    cos_out = dr.maximum(dr.abs(dr.dot(si.n, direction)), MIN_COS)
    return mi.Ray3f(dr.fma(direction, clearance / cos_out, si.p), direction, si.time,
                    si.wavelengths)


def _volpath_sample(self, scene, sampler, ray, medium=None, active=True):
    """``refracted_volpath``'s ``sample`` (compiled by ``dr.syntax`` in :func:`register`)."""
    ctx = mi.BSDFContext()
    phase_ctx = mi.PhaseFunctionContext(sampler)
    ray = mi.Ray3f(ray)
    medium = mi.MediumPtr(medium)
    radiance = mi.Spectrum(0.0)
    throughput = mi.Spectrum(1.0)
    depth = mi.UInt32(0)
    active = mi.Bool(active)
    channel = mi.UInt32(0)  # the project's media are grey
    nee = mi.Bool(self.surface_nee)
    # the ray left an event (medium scattering, or a smooth surface with surface_nee)
    # where an emitter was sampled: at this point, in a direction of this pdf
    after_scatter = mi.Bool(False)
    scatter_p = mi.Point3f(0.0)
    scatter_pdf = mi.Float(0.0)
    while dr.hint(active, max_iterations=self.max_depth, label="refracted_volpath"):
        in_medium = active & (medium != None)  # noqa: E711 (a pointer array)
        mei = medium.sample_interaction(ray, sampler.next_1d(in_medium), channel, in_medium)
        ray.maxt = dr.select(in_medium & mei.is_valid(), mei.t, ray.maxt)
        si = scene.ray_intersect(ray, ray_flags=mi.RayFlags.All, coherent=depth == 0,
                                 active=active)
        mei.t = dr.select(in_medium & (si.t < mei.t), dr.inf, mei.t)
        transmittance, free_flight_pdf = medium.transmittance_eval_pdf(mei, si, in_medium)
        pdf = free_flight_pdf[0]
        throughput = dr.select(in_medium, throughput * dr.select(
            pdf > 0, transmittance / pdf, 0.0), throughput)
        scatter = in_medium & mei.is_valid()
        on_surface = active & ~scatter
        radiance, throughput, scattered_ray, sampled_pdf = _scattering_event(
            scene, sampler, phase_ctx, mei, si, scatter, radiance, throughput)
        # a surface: its emission — after a sampled event weighted against the
        # next-event estimate of the same light (balance heuristic) — then a BSDF sample
        mis = _hit_weight(scene, si, scatter_p, scatter_pdf, on_surface & after_scatter)
        radiance += dr.select(on_surface, throughput * mis * si.emitter(scene).eval(
            si, on_surface), 0.0)
        on_surface &= si.is_valid()
        bsdf = si.bsdf(ray)
        smooth = on_surface & nee & mi.has_flag(bsdf.flags(), mi.BSDFFlags.Smooth)
        extinction = dr.select(in_medium, mei.combined_extinction[0], 0.0)
        radiance += dr.select(smooth, throughput * _surface_nee(
            scene, sampler, ctx, bsdf, si, extinction, smooth, self.surface_nee), 0.0)
        sample, weight = bsdf.sample(ctx, si, sampler.next_1d(on_surface),
                                     sampler.next_2d(on_surface), on_surface)
        throughput = dr.select(on_surface, throughput * weight, throughput)
        direction = si.to_world(sample.wo)
        surface_ray = _surface_ray(si, direction)
        crossing = on_surface & si.is_medium_transition()
        medium = dr.select(crossing, si.target_medium(direction), medium)
        ray = dr.select(scatter, scattered_ray, surface_ray)
        smooth_sampled = smooth & ~mi.has_flag(sample.sampled_type, mi.BSDFFlags.Delta)
        after_scatter = dr.select(scatter, True, dr.select(on_surface, smooth_sampled,
                                                           after_scatter))
        scatter_p = dr.select(scatter, mei.p, dr.select(smooth, si.p, scatter_p))
        scatter_pdf = dr.select(scatter, sampled_pdf, dr.select(smooth, sample.pdf, scatter_pdf))
        depth += 1
        active = (scatter | on_surface) & (depth < self.max_depth)
        active, throughput = _roulette(sampler, active, depth, throughput)
    return radiance, depth != 0, []


def _scattering_event(scene, sampler, phase_ctx, mei, si, scatter, radiance, throughput):
    """A scattering event in the medium where ``scatter``: the albedo weight (the free-flight
    weight was transmittance / pdf = 1 / σt), next-event estimation from the event (one emitter
    point, its transmittance through the homogeneous medium, unless something is between) and
    a phase function sample. Returns ``(radiance, throughput, scattered_ray, sampled_pdf)``."""
    throughput = dr.select(scatter, throughput * mei.sigma_s
                           * mei.combined_extinction[0] / mei.sigma_t[0], throughput)
    phase = mei.medium.phase_function()
    wo, phase_weight, sampled_pdf = phase.sample(
        phase_ctx, mei, sampler.next_1d(scatter), sampler.next_2d(scatter), scatter)
    ds, emitter_weight = scene.sample_emitter_direction(mei, sampler.next_2d(scatter), False,
                                                        scatter)
    phase_value, phase_pdf = phase.eval_pdf(phase_ctx, mei, ds.d, scatter)
    shadow = mi.Ray3f(mei.p, ds.d, ds.dist * (1.0 - mi.math.ShadowEpsilon), si.time,
                      si.wavelengths)
    visible = scatter & (ds.pdf > 0) & ~scene.ray_test(shadow, scatter)
    radiance += dr.select(visible, throughput * phase_value * emitter_weight
                          * dr.exp(-mei.sigma_t * ds.dist)
                          * dr.select(ds.delta, 1.0, _balance(ds.pdf, phase_pdf)), 0.0)
    throughput = dr.select(scatter, throughput * phase_weight, throughput)
    return radiance, throughput, mi.Ray3f(mei.p, wo, si.time, si.wavelengths), sampled_pdf


def _roulette(sampler, active, depth, throughput):
    """``(active, throughput)`` after Russian roulette past :data:`RR_DEPTH` events, as
    Mitsuba's ``volpath`` plays it (survival at most :data:`RR_MAX_Q`)."""
    active &= dr.max(mi.unpolarized_spectrum(throughput)) > 0
    roulette = active & (depth >= RR_DEPTH)
    survive = dr.minimum(dr.max(mi.unpolarized_spectrum(throughput)), RR_MAX_Q)
    active &= ~roulette | (sampler.next_1d(roulette) < survive)
    throughput = dr.select(roulette, throughput / survive, throughput)
    return active, throughput

#: Mitsuba integrators (class names) this module renders in place of, and with what.
SUBSTITUTES = {"PathIntegrator": PLUGIN_NAME, "VolumetricPathIntegrator": VOLUME_PLUGIN_NAME,
               "VolumetricSimplePathIntegrator": VOLUME_PLUGIN_NAME}


def _substitute(scene):
    """The plugin name that replaces ``scene``'s integrator, or None (rendered as it is)."""
    return SUBSTITUTES.get(str(scene.integrator()).split("[", 1)[0])


def _hit_weight(scene, si, prev_p, prev_pdf, active, enabled: bool = True):
    """MIS weight (balance heuristic) of an emitter hit by a ray sampled at ``prev_p`` with
    density ``prev_pdf`` (solid angle) where next-event estimation also sampled the emitters;
    1 where ``active`` is false (no next-event estimate covered this path), and 1 everywhere
    when ``enabled`` is False (nothing is traced: the integrator does no such estimate)."""
    if not enabled:
        return 1.0
    reference = dr.zeros(mi.Interaction3f)
    reference.p = prev_p
    emitter_pdf = scene.pdf_emitter_direction(reference, mi.DirectionSample3f(scene, si, reference),
                                              active)
    return dr.select(active, _balance(prev_pdf, emitter_pdf), 1.0)


def _surface_nee(scene, sampler, ctx, bsdf, si, extinction, active, enabled: bool = True):
    """Next-event estimate at a smooth (non-delta) surface point ``si``: one emitter sample,
    the BSDF's value towards it, a shadow ray, the transmittance ``exp(−extinction·distance)``
    of a homogeneous medium (``extinction`` per scene unit; 0 in clear water or air), and the
    balance heuristic against BSDF sampling (weight 1 for delta lights such as spots). Returns
    the radiance to add, before the path throughput; 0 without tracing anything when
    ``enabled`` is False (scenes whose lights BSDF sampling reaches, such as LED targets)."""
    if not enabled:
        return 0.0
    ds, emitter_weight = scene.sample_emitter_direction(si, sampler.next_2d(active), True, active)
    value, pdf = bsdf.eval_pdf(ctx, si, si.to_local(ds.d), active)
    mis = dr.select(ds.delta, 1.0, _balance(ds.pdf, pdf))
    return dr.select(active & (ds.pdf > 0), value * emitter_weight * mis
                     * dr.exp(-extinction * ds.dist), 0.0)


def _balance(pdf_a, pdf_b):
    """The balance heuristic's weight of the strategy with density ``pdf_a``."""
    return dr.select(pdf_a > 0, pdf_a / (pdf_a + pdf_b), 0.0)


def render_integrator(mitsuba, scene):
    """The integrator to render ``scene`` with: :data:`PLUGIN_NAME` in place of Mitsuba's
    ``path``, :data:`VOLUME_PLUGIN_NAME` in place of ``volpath`` (same ``max_depth``), ``None``
    (the scene's own) for any other integrator."""
    plugin = _substitute(scene)
    if plugin is None:
        return None
    match = re.search(r"max_depth\s*=\s*(-?\d+)", str(scene.integrator()))
    register(mitsuba)
    return mitsuba.load_dict({"type": plugin, "max_depth": int(match.group(1)) if match else 8,
                              "surface_nee": has_point_lights(mitsuba, scene)})


def has_point_lights(mitsuba, scene) -> bool:
    """Whether ``scene`` has emitters at a point (spot, point lights: lit targets), which only
    next-event estimation at the surfaces they light can reach."""
    return any(mitsuba.has_flag(e.flags(), mitsuba.EmitterFlags.DeltaPosition)
               for e in scene.emitters())


def integrator_name(mitsuba, scene) -> str:
    """The plugin name :func:`render_integrator` renders ``scene`` with (for manifests)."""
    return _substitute(scene) or str(scene.integrator()).split("[", 1)[0]
