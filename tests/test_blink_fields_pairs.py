"""Crowd decoding in fields: the footprint aperture, neighbours and one LED read twice; never guessed."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from fgloc.camera.blink_codes import code_book
from fgloc.camera.blink_crowd_decoding import merge_reading, with_neighbour
from fgloc.camera.blink_decoder import DecodedReading, DecoderConfig, decode_view
from fgloc.camera.blink_pairs import PairConfig, footprint
from fgloc.camera.blink_word_fit import WordFitConfig
from fgloc.camera.intrinsics import CameraIntrinsics
from fgloc.core.model import CameraPose
from fgloc.drivers.blink_frames import (
    BlinkRenderConfig,
    close_groups,
    close_pairs,
    motes_with_codes,
    points_at_pixels,
    render_view,
)
from fgloc.drivers.rendered_camera import LedScene, RenderedCamera, add_spot
from fgloc.survey.coded_readings import field_intrinsics
from fgloc.survey.field_plans import frames_for
from tests.test_blink_pairs import _stack  # noqa: E402  (the same synthetic samples)

BOOK = code_book(100)
FIELD = field_intrinsics(CameraIntrinsics.from_fov(320, 240, 50.0))  #: 320 x 120 fields
LABEL_PX = 1.0  #: any reading farther than this from the mote its code names is a mislabel
NOISE = 2.0 * math.sqrt(2.0)  #: per-pixel noise of a frame difference of the synthetic stacks (DN)
#: the levers this round added, off: the whole square as aperture, no neighbour pairing
OLD = PairConfig(aperture_fraction=0.0, neighbour_px=0.0)


def _field_view(seed: int, uv_of: str, n: int, size_px: float, flux: float
                ) -> tuple[list, np.ndarray, np.ndarray, float, float, float]:
    """One rendered field view (320 x 120 at 59.94 Hz, drops, 1 % repeats, no lamps or glints)
    of ``n`` pairs ``size_px`` apart (``uv_of`` "pairs") or ``n`` crowds of three linked
    within ``size_px`` ("groups"), LEDs of ``flux`` DN per field. (frames, uv, ids, pan, tilt, period)."""
    rng = np.random.default_rng(seed)
    pan, tilt = rng.uniform(-1.0, 1.0), rng.uniform(-0.5, 0.2)
    if uv_of == "pairs":
        centres = np.column_stack([np.linspace(30, 290, n) + rng.uniform(-5, 5, n), rng.uniform(25, 95, n)])
        uv = close_pairs(centres, np.full(n, size_px), rng)
    else:
        uv = close_groups(n, 3, FIELD.width, FIELD.height, rng, link_px=size_px, clear_px=16.0)
    ids = rng.choice(100, len(uv), replace=False)
    pts = points_at_pixels(FIELD, pan, tilt, uv, rng.uniform(3.0, 20.0, len(uv)))
    base = BlinkRenderConfig(duplicate_rate=0.01)
    cfg = replace(base, frame_rate_hz=2.0 * base.frame_rate_hz, led_flux=flux, static_flux=0.5 * base.static_flux)
    motes = motes_with_codes({f"m{k}": pts[k] for k in range(len(ids))},
                             {f"m{k}": BOOK.bits(int(i)) for k, i in enumerate(ids)}, round(1 / cfg.frame_rate_hz, 5), rng)
    cam = RenderedCamera(CameraPose(np.zeros(3), np.eye(3)), LedScene(positions={}))
    frames = render_view(cam, FIELD, pan, tilt, motes, frames_for(BOOK.length), rng, cfg)
    return frames, uv, ids, pan, tilt, 1.0 / cfg.frame_rate_hz


FIT = DecoderConfig(word_fit=WordFitConfig())  #: the decoder with the light-curve fit (step 8)


def _read(seed: int, uv_of: str, n: int, size_px: float, flux: float, configs: tuple[PairConfig, ...],
          decoder: DecoderConfig | None = None) -> list[int]:
    """Readings within LABEL_PX of their mote, per config; asserts no reading elsewhere and
    that every crowd reading names the other LEDs of its own crowd."""
    frames, uv, ids, pan, tilt, period = _field_view(seed, uv_of, n, size_px, flux)
    truth = {int(i): uv[k] for k, i in enumerate(ids)}
    size = 2 if uv_of == "pairs" else 3
    out = []
    for cfg in configs:
        res = decode_view(frames, period, BOOK, FIELD, pan, tilt, decoder, pairs=cfg)
        for r in res.readings:
            assert math.dist((r.u, r.v), truth[r.index]) < LABEL_PX  # mislabels 0
            k = int(np.flatnonzero(ids == r.index)[0])
            crowd = {int(ids[m]) for m in range(size * (k // size), size * (k // size) + size)}
            if r.partner is not None:
                assert r.partner in crowd - {r.index}
            assert set(r.group) <= crowd - {r.index}
        out.append(len(res.readings))
    return out


def test_footprint_keeps_the_spot_on_few_pixels() -> None:
    """A Gaussian spot (sigma 1.2 px): the footprint at 0.1 of the peak keeps ~90 % of the flux
    (1 - fraction for a continuous Gaussian) on ~2 pi sigma^2 ln 10 px, not the 121 of the square."""
    img = np.zeros((21, 21))
    add_spot(img, 10.3, 9.8, 1000.0, 1.2)
    core = np.zeros(img.shape, bool)
    core[5:16, 5:16] = True
    fp = footprint(img, core, 0.1)
    assert abs(img[fp].sum() / img[core].sum() - 0.9) < 0.05
    assert abs(int(fp.sum()) - 2 * math.pi * 1.2**2 * math.log(10)) < 6
    assert footprint(np.zeros(img.shape), core, 0.1) is core  # no light: the whole square


def test_dim_field_pairs_read_with_the_footprint_aperture() -> None:
    """Pairs 5 px apart in fields of dim LEDs (375 DN per field): the whole square's noise
    refuses every one (one-LED step under 12 sigmas); the footprint reads most, none wrong."""
    old = new = 0
    for seed in (1, 3):
        o, n = _read(seed, "pairs", 5, 5.0, 375.0, (OLD, PairConfig()))
        old, new = old + o, new + n
    assert old == 0 and new >= 14  # of 20 LEDs (16 measured)


def test_field_pairs_7px_read_with_a_neighbour() -> None:
    """Pairs 7 px apart in fields: one LED read alone, the other refused (its neighbour's light
    in its aperture); the neighbour rule reads the pair, naming each other, none wrong. Measured
    with the level decoder alone (no light-curve fit), which leaves the pairs to the rule; the
    fit reads most such LEDs singly before the pair stage, and the rule still adds."""
    lone = PairConfig(neighbour_px=0.0)
    levels = DecoderConfig(word_fit=None)
    old = new = fit_lone = fit_new = 0
    for seed in (4, 5, 6):
        o, n = _read(seed, "pairs", 5, 7.0, 750.0, (lone, PairConfig()), levels)
        old, new = old + o, new + n
        o, n = _read(seed, "pairs", 5, 7.0, 750.0, (lone, PairConfig()), FIT)
        fit_lone, fit_new = fit_lone + o, fit_new + n
    assert new >= old + 8 and new >= 24  # of 30 LEDs (15 -> 26 measured)
    assert fit_new >= max(new, fit_lone) and fit_lone > old  # with the fit: 24 alone, 29 with the rule


def test_field_crowds_of_three_with_neighbours() -> None:
    """Crowds of three linked within 7 px: with neighbours every LED of the view is read (9 of 9),
    groups naming their own two others; without, 6 (the level decoder alone; with the
    light-curve fit reading LEDs singly first, still all 9)."""
    configs = (PairConfig(max_group=3, neighbour_px=0.0), PairConfig(max_group=3))
    old, new = _read(0, "groups", 3, 7.0, 750.0, configs, DecoderConfig(word_fit=None))
    assert old <= 6 and new == 9
    assert _read(0, "groups", 3, 7.0, 750.0, configs, FIT)[1] == 9


def _reading(index: int, u: float, v: float) -> DecodedReading:
    return DecodedReading(index, u, v, 0.05, 0.0, 0.0, 10)


def test_neighbour_pair_must_contain_the_known_led() -> None:
    """A synthetic pair 6 px apart (words 3 and 41): paired with a reading of word 3 at its
    LED it is accepted; with a reading of another word there, or of word 3 elsewhere, refused."""
    a, b = (17.0, 20.2), (23.0, 20.2)
    stack, valid, pos = _stack([(3, 0), (41, 7)], [a, b], seed=5)
    cfg = PairConfig()
    ok, took = with_neighbour(stack, valid, pos, *b, BOOK, NOISE, [_reading(3, *a)], [], cfg)
    assert ok.ok and ok.index is not None and set(ok.index) == {3, 41} and took is None, ok.reason
    for known in (_reading(77, *a), _reading(3, a[0], a[1] + 1.5)):
        bad, _ = with_neighbour(stack, valid, pos, *b, BOOK, NOISE, [known], [], cfg)
        assert not bad.ok and "neither LED" in bad.reason
    far, _ = with_neighbour(stack, valid, pos, *b, BOOK, NOISE, [_reading(3, *a)], [], replace(cfg, neighbour_px=5.0))
    assert not far.ok  # no neighbour within 5 px


def test_same_code_twice_in_one_place_is_one_led_elsewhere_a_duplicate() -> None:
    """merge_reading: a code read again within same_px replaces the first reading; farther away
    it is kept beside it (the view decoder refuses both as duplicates)."""
    rs = [_reading(5, 10.0, 10.0), _reading(6, 14.0, 10.0)]
    merge_reading(rs, _reading(5, 10.4, 10.3), 1.0)
    assert [(r.index, r.u) for r in rs] == [(5, 10.4), (6, 14.0)]
    merge_reading(rs, _reading(6, 20.0, 10.0), 1.0)
    assert [r.index for r in rs] == [5, 6, 6]


def test_same_word_pair_still_refused() -> None:
    """Two LEDs 6 px apart blinking the same word (rotated): never read as a pair, alone or
    with the other as a known neighbour."""
    a, b = (17.0, 20.2), (23.0, 20.2)
    stack, valid, pos = _stack([(12, 0), (12, 5)], [a, b], seed=6)
    res, _ = with_neighbour(stack, valid, pos, *b, BOOK, NOISE, [_reading(12, *a)], [((a[0], a[1]), 0)],
                            PairConfig())
    assert not res.ok
