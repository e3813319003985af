"""Simulated (pan, tilt) readings of a coded survey, for accuracy comparisons with the sequential one.

A sequential survey centres each lit LED and reads the head: one independent head
error per reading (the paper's model, :func:`fgloc.sim.scenes.observe`). A coded
survey reads the head **once per view** and takes every mote in the view off-centre,
so a reading is composed of

* the head position error of that view, **shared by every mote in the view**
  (``CodedNoise.head_sigma`` per axis, radians);
* the decoder's centroid error, independent per reading (``decoder_sigma_pan`` /
  ``decoder_sigma_tilt``, radians at the survey zoom, as measured by
  ``scripts/blink_montecarlo.py``; a pixel error, so in angle divided by the
  magnification in a refinement view);
* an optional focal-length calibration error (``fx_error``, relative): the pixel ->
  pan-tilt composition (:func:`fgloc.camera.pixel_angles.pixel_to_pan_tilt`) then
  uses focal lengths ``(1 + fx_error)`` times the true ones, an error that grows with
  the distance from the image centre.

Views: each camera covers the deployment area with :func:`plan_views` at the survey
zoom, then records its refinement passes (:func:`plan_refinement`: motes whose nearest
neighbour is closer than ``separation_px``, at the lowest zoom that separates them).
A mote gives a reading in **every** recorded view that contains it and separates it
(views overlap, so many motes are read twice, each time with that view's head error);
``every_view=False`` keeps its first reading only. Motes no view separates, and readings
the decoder misses twice (``miss_rate`` per recording, one retry), are missing
(reported, never guessed).

Pair decoding (``pair_rate`` > 0): crowded groups of exactly two motes are read in the
wide views with that probability per pair (:func:`fgloc.survey.field_plans.pair_decoding`),
with the pair decoder's centroid error (``pair_sigma_pan`` / ``pair_sigma_tilt``), and
need no refinement; the others are refined as before. Group decoding (``group_rate`` > 0)
does the same for crowded groups of exactly three
(:func:`fgloc.survey.field_plans.group_decoding`, ``group_sigma_pan`` / ``group_sigma_tilt``).

Each reading carries ``sigma = sqrt(head_sigma^2 + decoder^2)`` as its total noise, with
``decoder`` the centroid error mapped to angles at that pixel
(:func:`decoder_angle_sigmas`; ``sigma`` with their RMS, ``sigma_axes`` per axis), and names its view
(``view = "<camera>/v<k>"``, k the view's index in the camera's recording order) with
``view_sigma = head_sigma``, the part of ``sigma`` the view's readings share, and
``view_pan``, the head pan the view was read at: the solver estimates one (pan, tilt)
head error per view (:func:`fgloc.solve.joint.view_offsets`,
:mod:`fgloc.factors.view_offset`) and takes only the decoder part as independent.
``shared_head=False`` (one head error per reading, a diagnostic) names no views;
``views=False`` (the readings as independent with one sigma, as before view offsets
existed) names no views and gives no ``sigma_axes``.

Angles radians; pixels OpenCV convention.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from fgloc.camera.intrinsics import CameraIntrinsics
from fgloc.camera.pixel_angles import pan_tilt_to_pixel, pixel_to_pan_tilt
from fgloc.core.geometry import FloatArray, bearing_pan_tilt, world_to_base
from fgloc.core.model import CameraPose, Observation
from fgloc.survey.view_planner import coverage, neighbour_px, plan_refinement, plan_views


@dataclass(frozen=True)
class CodedNoise:
    """Error model of coded readings (radians; ``fx_error`` relative; ``miss_rate`` per recording)."""

    head_sigma: float = math.radians(0.1)
    decoder_sigma_pan: float = math.radians(0.01)
    decoder_sigma_tilt: float = math.radians(0.01)
    fx_error: float = 0.0
    miss_rate: float = 0.0
    separation_px: float = 4.0
    field_rows: bool = False  #: decoding single fields: half the vertical resolution
    every_view: bool = True  #: a reading from every view a mote is decodable in (False: its first only)
    shared_head: bool = True  #: one head error per view (False: per reading, a diagnostic)
    levels: tuple[float, ...] = (1 / 9, 3 / 9, 1.0)
    views: bool = True  #: name each reading's view (with view_sigma = head_sigma) when the head error is shared
    #: pair decoding: share of crowded groups of exactly two read in the wide view as a pair (0: off)
    pair_rate: float | tuple[tuple[float, float], ...] = 0.0  #: or by third-mote distance (pair_rate_table)
    pair_sigma_pan: float | None = None  #: pair-decoded centroid error (radians at the survey zoom; None: decoder's)
    pair_sigma_tilt: float | None = None
    #: group decoding: share of crowded groups of exactly three read in the wide view as a group (0: off)
    group_rate: float | tuple[tuple[float, float], ...] = 0.0  #: or by fourth-mote distance
    group_sigma_pan: float | None = None  #: group-decoded centroid error (radians, survey zoom; None: the pair's)
    group_sigma_tilt: float | None = None


@dataclass(frozen=True)
class CodedReadings:
    """Observations of one coded survey and what it could not read (per camera counts)."""

    observations: list[Observation]
    views: dict[str, int]
    refined: dict[str, int]
    unresolved: dict[str, int]
    missed: dict[str, int]


def coded_observations(
    camera_ids: list[str], cameras: list[CameraPose], node_ids: list[str], nodes: FloatArray,
    area: FloatArray, intr: CameraIntrinsics, noise: CodedNoise, rng: np.random.Generator,
) -> CodedReadings:
    """Simulated coded readings of ``nodes`` (N, 3) by ``cameras`` (truth poses, gauge frame);
    ``area`` (M, 3) samples the deployment area each camera's wide views must cover."""
    out: list[Observation] = []
    n_views: dict[str, int] = {}
    refined: dict[str, int] = {}
    unresolved: dict[str, int] = {}
    missed: dict[str, int] = {}
    for cid, cam in zip(camera_ids, cameras):
        region = np.column_stack(bearing_pan_tilt(world_to_base(cam.rotation, cam.position, area)))
        d = world_to_base(cam.rotation, cam.position, nodes)
        pt = np.column_stack(bearing_pan_tilt(d / np.linalg.norm(d, axis=1, keepdims=True)))
        wide = plan_views(intr, region)
        paired = np.zeros(len(pt), bool)  # crowded motes the pair decoder reads in the wide views
        if noise.pair_rate:
            from fgloc.survey.field_plans import pair_decoding

            paired = pair_decoding(intr, pt, noise.separation_px, noise.pair_rate, rng, noise.field_rows).resolved
        grouped = np.zeros(len(pt), bool)  # crowded motes the group decoder reads in the wide views
        if noise.group_rate:
            from fgloc.survey.field_plans import group_decoding

            grouped = group_decoding(intr, pt, noise.separation_px, noise.group_rate, rng, noise.field_rows).resolved
            paired = paired | grouped
        passes, _ = plan_refinement(intr, pt, noise.separation_px, noise.levels, start=wide[-1] if wide else (0, 0),
                                    field_rows=noise.field_rows, needed=~paired if paired.any() else None)
        # every (view, mote) pair that gives a reading: the mote is inside the view and separable at its zoom
        need = noise.separation_px / np.maximum(neighbour_px(pt, intr, noise.field_rows), 1e-12)
        all_views = [(p, t, 0.0) for p, t in wide] + [(p, t, rp.zoom) for rp in passes for p, t in rp.views]
        pairs: list[tuple[tuple[float, float, float], int]] = []
        seen = np.zeros(len(pt), bool)
        for view in all_views:
            zi = intr.at_zoom(view[2])
            ok = coverage(zi, pt, np.array([view[:2]]), 12.0)[0] & ((need <= zi.fx / intr.fx) | (
                paired & (view[2] == 0.0))) & ~(
                seen if not noise.every_view else np.zeros(len(pt), bool))
            pairs += [(view, int(j)) for j in np.flatnonzero(ok)]
            seen |= ok
        n_unres = int((~seen).sum())
        wide_fy = field_intrinsics(intr).fy if noise.field_rows else intr.fy
        head_err: dict[tuple[float, float, float], np.ndarray] = {}
        n_missed = 0
        view_name = {v: f"{cid}/v{k:03d}" for k, v in enumerate(dict.fromkeys(v for v, _ in pairs))}
        named = noise.shared_head and noise.views and noise.head_sigma > 0
        for view, j in pairs:
            if rng.random() < noise.miss_rate**2:  # missed in the recording and in its retry
                n_missed += 1
                continue
            if view not in head_err or not noise.shared_head:
                head_err[view] = rng.normal(0.0, noise.head_sigma, 2)
            hp, ht, z = view
            zi = intr.at_zoom(z)
            dec = field_intrinsics(zi) if noise.field_rows else zi
            uv, _ = pan_tilt_to_pixel(dec, pt[j:j + 1, 0], pt[j:j + 1, 1], hp, ht)
            # the centroid error is a pixel error (the same in a zoomed view's pixels)
            sigma_px = np.array([noise.decoder_sigma_pan * intr.fx, noise.decoder_sigma_tilt * wide_fy])
            if paired[j] and z == 0.0 and need[j] > 1.0:  # read as one of a pair: the pair centroid error
                sigma_px = np.array([
                    (noise.pair_sigma_pan if noise.pair_sigma_pan is not None else noise.decoder_sigma_pan) * intr.fx,
                    (noise.pair_sigma_tilt if noise.pair_sigma_tilt is not None else noise.decoder_sigma_tilt)
                    * wide_fy])
            if grouped[j] and z == 0.0 and need[j] > 1.0:  # read as one of a group of three
                gp = noise.group_sigma_pan if noise.group_sigma_pan is not None else noise.pair_sigma_pan
                gt = noise.group_sigma_tilt if noise.group_sigma_tilt is not None else noise.pair_sigma_tilt
                sigma_px = np.array([(gp if gp is not None else noise.decoder_sigma_pan) * intr.fx,
                                     (gt if gt is not None else noise.decoder_sigma_tilt) * wide_fy])
            uv = uv + rng.normal(0.0, 1.0, 2) * sigma_px
            assumed = replace(dec, fx=dec.fx * (1.0 + noise.fx_error), fy=dec.fy * (1.0 + noise.fx_error))
            e = head_err[view]
            p, t = pixel_to_pan_tilt(assumed, uv, hp + e[0], ht + e[1])
            sd_pan, sd_tilt = decoder_angle_sigmas(dec, uv[0], sigma_px, hp, ht)
            sig = math.hypot(noise.head_sigma, math.sqrt(0.5 * (sd_pan**2 + sd_tilt**2)))
            axes = (math.hypot(noise.head_sigma, sd_pan), math.hypot(noise.head_sigma, sd_tilt))
            out.append(Observation(cid, node_ids[j], float(np.remainder(p[0] + math.pi, 2 * math.pi) - math.pi),
                                   float(t[0]), sigma=sig, view=view_name[view] if named else None,
                                   view_sigma=noise.head_sigma if named else None,
                                   view_pan=hp if named else None, sigma_axes=axes if noise.views else None))
        n_views[cid] = len(wide) + sum(len(rp.views) for rp in passes)
        refined[cid] = int(sum(rp.targets for rp in passes))
        unresolved[cid] = n_unres
        missed[cid] = n_missed
    return CodedReadings(out, n_views, refined, unresolved, missed)


def decoder_angle_sigmas(intr: CameraIntrinsics, uv: FloatArray, sigma_px: FloatArray, head_pan: float,
                         head_tilt: float) -> tuple[float, float]:
    """Pan and tilt sigma (radians) of a centroid at pixel ``uv`` with pixel sigmas ``sigma_px`` (u, v).

    The pixel error maps to (pan, tilt) through the local Jacobian of
    :func:`pixel_to_pan_tilt` (central differences, half a pixel): smaller off-centre
    (cos^2 of the off-axis angle), larger in pan at steep tilt. (Their small correlation
    is left out: a reading carries one sigma per axis.)
    """
    h = 0.5
    uv4 = np.asarray(uv, dtype=float) + np.array([[h, 0.0], [-h, 0.0], [0.0, h], [0.0, -h]])
    p, t = pixel_to_pan_tilt(intr, uv4, head_pan, head_tilt)
    dp = np.remainder(np.array([p[0] - p[1], p[2] - p[3]]) + math.pi, 2 * math.pi) - math.pi
    jac = np.array([dp, [t[0] - t[1], t[2] - t[3]]]) / (2 * h)  # rows pan, tilt; columns u, v
    var = ((jac * np.asarray(sigma_px, dtype=float)[None, :]) ** 2).sum(axis=1)
    return math.sqrt(float(var[0])), math.sqrt(float(var[1]))


def field_intrinsics(intr: CameraIntrinsics) -> CameraIntrinsics:
    """One field of interlaced video: every second row (half the height and ``fy``; field row
    r is frame row 2r, so ``cy`` halves too)."""
    return replace(intr, fy=0.5 * intr.fy, cy=0.5 * intr.cy, height=intr.height // 2)


@dataclass(frozen=True)
class AccuracyTrial:
    """Errors of one scene solved from sequential and from coded readings, on the nodes both
    localized: squared position errors (baseline units^2) and NEES (planar, 2 dof)."""

    sq_seq: FloatArray
    sq_coded: FloatArray
    nees_seq: FloatArray
    nees_coded: FloatArray
    readings: CodedReadings
    dropped: int  #: nodes only the sequential solve localized


def accuracy_trial(seed: int, n_nodes: int, intr: CameraIntrinsics, noise: CodedNoise,
                   area_step: float = 0.02) -> AccuracyTrial:
    """One seeded paper scene (:func:`fgloc.sim.scenes.paper_scenario`, head sigma
    ``noise.head_sigma``): sequential readings as the simulator takes them, coded readings by
    :func:`coded_observations`; both solved by :func:`fgloc.solve.joint.solve_survey`."""
    from fgloc.evaluate.score import nees
    from fgloc.sim.scenes import PaperScenario, paper_scenario
    from fgloc.solve.joint import solve_survey

    seq = paper_scenario(PaperScenario(n_nodes=n_nodes, sigma=noise.head_sigma, seed=seed))
    assert seq.truth is not None
    g = np.arange(0.0, 1.0 + 1e-9, area_step)
    xx, yy = np.meshgrid(g, g)
    area = np.column_stack([xx.ravel(), yy.ravel(), np.zeros(xx.size)])
    cams = [seq.truth.cameras[c] for c in seq.camera_ids]
    rng = np.random.default_rng([seed, 16])
    readings = coded_observations(seq.camera_ids, cams, seq.node_ids, seq.truth_node_array(), area, intr, noise, rng)
    coded = replace(seq, observations=readings.observations)
    for cached in ("observation_table", "view_ids"):
        coded.__dict__.pop(cached, None)
    r_seq, r_cod = solve_survey(seq), solve_survey(coded)
    ids = [n for n in seq.node_ids if n in r_seq.nodes and n in r_cod.nodes]
    truth = np.array([seq.truth.nodes[n][:2] for n in ids])
    out = []
    for r in (r_seq, r_cod):
        e = np.array([r.nodes[n].position[:2] for n in ids]) - truth
        cov = np.array([r.nodes[n].covariance for n in ids])
        out += [np.sum(e**2, axis=1), nees(e, cov)]
    return AccuracyTrial(out[0], out[2], out[1], out[3], readings, sum(n not in r_cod.nodes for n in r_seq.nodes))
