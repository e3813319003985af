"""The coded survey's settings (its levers and knobs) and its per-run counters.

:class:`CodedSettings` is what rig.json ``"coded"`` and ``fgloc survey --coded`` choose
(:mod:`fgloc.survey.coded_levers`); :class:`CodedStats` counts what one run of
:class:`fgloc.survey.coded.CodedSurvey` did. Radians, seconds, pixels.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

from fgloc.camera.blink_decoder import DecoderConfig
from fgloc.camera.blink_word_fit import WordFitConfig


@dataclass(frozen=True)
class CodedSettings:
    """Coded-survey knobs (radians, seconds, pixels)."""

    periods: int = 3  #: code periods recorded per view (frames = periods x L + 2)
    retries: int = 1  #: extra recordings of a view with curable refusals
    start_attempts: int = 3  #: broadcast starts while some mote has not confirmed
    report_wait_s: float = 0.2  #: how long to collect the motes' blink reports per broadcast
    margin_px: float = 16.0  #: a view covers a direction this far inside the image
    #: sampling of the search box for the planner, in units of ``margin_px / fx``: every direction
    #: is then within half a margin of a covered sample, so >= 8 px inside some view (the decoder
    #: refuses blobs within 7 px of the border)
    target_step: float = 0.7
    decoder: DecoderConfig = field(default_factory=DecoderConfig)
    #: refinement zooms (fractions of the optical range, ascending; :meth:`CameraIntrinsics.at_zoom`:
    #: 3x, 6x, then 10x), used where the rig can record at other zooms (the in-process rig); journals
    #: that recorded no ladder resume with :data:`~fgloc.survey.coded_levers.LEGACY_LEVELS` (2x, 4x, 10x)
    levels: tuple[float, ...] = (2 / 9, 5 / 9, 1.0)
    #: how a view with curable refusals is recorded again: ``"continue"`` goes on recording L more
    #: frames without moving and decodes the whole recording in sliding windows
    #: (:func:`~fgloc.camera.blink_decoder.decode_windows`); ``"burst"`` records a new 3L + 2
    retry: str = "continue"
    #: crowded motes: ``"zoom"`` refinement ladder only; ``"radio"`` first pauses colour classes by
    #: radio and records the wide views again (:mod:`fgloc.survey.coded_separation`), then zooms
    #: on what is left
    separate: str = "zoom"
    #: fallback of a mote a camera did not decode: ``"blobs"`` looks at every blob the camera left
    #: unexplained; ``"predicted"`` first places the mote from the other cameras' readings
    #: (:func:`~fgloc.survey.coded_separation.predict_directions`) and looks only at the blobs
    #: within :data:`~fgloc.survey.coded_levers.PREDICTED_RADIUS` of where it must be (none there: not found, no search);
    #: ``"round"``: as ``"predicted"``, after one round in which only the motes it would search blink, recorded
    #: at the survey zoom where it pays (:mod:`fgloc.survey.coded_fallback_round`; the default)
    fallback: str = "round"
    #: ``"fields"``: record and decode interlaced video field by field (59.94 Hz, every second
    #: row; the motes' bit period one field), on rigs that record fields and heads with
    #: interlaced video; ``"frames"``: whole frames at 29.97 Hz
    video: str = "frames"
    #: ``"on"``: a recording starts with L + 2 frames and stops there when they show no blob (an
    #: empty view), else goes on to 3L + 2 (one continuous recording); ``"off"``: always 3L + 2
    probe: str = "on"
    #: ``"on"``: refused blobs are also tried as two LEDs and labelled by both code words when
    #: that is unique (:mod:`fgloc.camera.blink_pairs`; rotation-free books); ``"groups"``: and a
    #: refused pair is tried as three LEDs (:mod:`fgloc.camera.blink_groups`); ``"off"``: not
    pairs: str = "groups"
    #: radio-separation rounds (``separate "radio"``): ``"short"`` records ``L + 2`` samples per
    #: round view and labels each blob against the round's candidates (the lit class's motes with
    #: their predicted pixels, :func:`fgloc.camera.blink_candidates.decode_candidates`); a retry
    #: continues by ``L``. ``"full"``: ``3L + 2`` samples decoded blind, as a wide view (the
    #: default of journals written before this lever, :data:`~fgloc.survey.coded_levers.LEGACY`)
    rounds: str = "short"
    #: radio-separation round order: ``"class"`` (every camera records a class's views, a barrier,
    #: the next class) or ``"view"`` (each camera visits its round views once, the base station
    #: cycling the classes each view needs; :mod:`fgloc.survey.coded_view_major`). Both defaults
    #: measured faster (docs/blink-codes.md, "Short and view-major rounds, measured")
    round_order: str = "view"
    #: refinement rungs: ``"focus"`` carries on only the blobs a rung's tiles show where it looked
    #: (near a chased blob) and hands static lamps to the fallback (:mod:`fgloc.survey.coded_ladder`);
    #: ``"climb"``: every blob its tiles leave unexplained (the default of journals written before this lever)
    ladder: str = "focus"
    #: view decoding: ``"fit"`` gives a blob the level decoder refuses (its levels or its bits) the
    #: light-curve fit (:mod:`fgloc.camera.blink_word_fit`: motes whose bit edges fall inside the
    #: exposure, motes on an offset background; the default, with ``length "adaptive"`` measured
    #: fastest at 100 and 1000 motes, docs/blink-codes.md "New light and pair labels");
    #: ``"levels"``: the level decoder alone (the default of journals written before this lever)
    decode: str = "fit"
    #: a view's first recording: ``"fixed"`` 3L + 2 frames; ``"adaptive"`` stops at 2L + 2 when
    #: the decode of those leaves no blob unexplained, else goes on to 3L + 2 as one recording
    #: (:func:`fgloc.survey.coded_recording.record_adaptive`; the default, with ``decode "fit"``);
    #: ``"fixed"``: always ``3L + 2`` (the default of journals written before this lever)
    length: str = "adaptive"
    #: ladder ``"focus"``: which blobs are explained before a rung: ``"readings"`` those within 1.5 px
    #: of a reading of the camera (merged blobs never); ``"views"``: between two refinement rungs,
    #: also a blob whose neighbourhood another recording of the camera read cleanly
    #: (:func:`~fgloc.survey.coded_ladder.resolved_elsewhere`; the default before stop 40);
    #: ``"crowds"`` (the default): also a wide-pass blob whose clean neighbourhood another
    #: recording read two motes or more in (a crowd read apart); ``"readings"`` is the default of
    #: journals written before this lever
    explain: str = "crowds"
    #: fallback ``"predicted"``/``"round"``: the blobs a camera searches for a mote another camera
    #: read: ``"disk"``: every unexplained blob within 3° of its predicted direction; ``"epipolar"``:
    #: of those, only the ones near the plane through both cameras and the reading's ray
    #: (:mod:`fgloc.survey.coded_epipolar`; the default); ``"disk"`` is the default of journals
    #: written before this lever
    looks: str = "epipolar"
    #: the fallback's searches: ``"paired"``: the one-camera searches of different cameras zipped
    #: into batches of one node per camera, lit together (:mod:`fgloc.survey.coded_paired`; the
    #: default); ``"one"``: one node at a time (the default of journals written before this lever)
    searches: str = "paired"
    #: fallback ``"round"``: which motes a camera did not read its round views cover (by their
    #: predicted directions): ``"searched"``: those the fallback would search (an unexplained blob
    #: where it looks for them, :func:`~fgloc.survey.coded_levers.blobs_near`; the default);
    #: ``"placed"``: every placed one (the default of journals written before this lever)
    covers: str = "searched"
    #: ``length "adaptive"``: a first recording that goes on to 3L + 2: ``"kept"`` keeps the
    #: readings of its first 2L + 2 frames' decode that the whole decode lacks
    #: (:func:`fgloc.camera.blink_decoder.supplement_decode`; the default); ``"dropped"``: the
    #: whole recording's decode alone (the default of journals written before this lever)
    first_window: str = "kept"
    #: ``"together"``: a zoom to a rung (or back to the survey zoom) runs during the move to the
    #: next view, on heads whose model zooms while moving and whose driver has ``move_and_zoom``
    #: (the default); ``"apart"``: zoom, then move (the default of journals written before this lever)
    zoom_moves: str = "together"
    #: which views may be recorded a second time: ``"wide"``: the wide pass and the radio rounds
    #: (:func:`~fgloc.survey.coded_ladder.may_record_again`; the default); ``"first_rung"``: also the
    #: first refinement rung's tiles; ``"all"``: every view (the default before stop 40, and of
    #: journals written before this lever)
    retries_at: str = "wide"
    #: how the wide pass's views and each rung's tiles are chosen: ``"minimal"``: the fewest that
    #: cover what they must, a chased blob whole in one tile
    #: (:func:`~fgloc.survey.view_planner.fewest_views`; the default, but a greedy cover of more than
    #: :data:`~fgloc.survey.view_planner.FEWEST_MAX_VIEWS` views is kept); ``"greedy"`` (the default of
    #: journals written before this lever): each next view the one covering the most still uncovered
    tiling: str = "minimal"

    def view_decoder(self) -> DecoderConfig:
        """The decoder configuration of the views, as ``decode`` chooses."""
        return replace(self.decoder, word_fit=WordFitConfig() if self.decode == "fit" else None)


@dataclass
class CodedStats:
    """What the coded phase did in this run."""

    views: int = 0
    recordings: int = 0
    second_recordings: int = 0
    readings: int = 0
    ambiguous: int = 0
    duplicate: int = 0
    rejected: int = 0
    unassigned: int = 0
    confirmed: int = 0
    fallback_nodes: int = 0
    classes: int = 0  #: radio separation: colour classes (rounds)
    round_views: int = 0  #: radio separation: views recorded in rounds
    fallback_round_views: int = 0  #: fallback "round": views recorded with only the fallback's motes lit
    pause_updates: int = 0  #: radio separation: pause-by-bitmap updates sent
    rounds_s: float = 0.0  #: radio separation: priced field time of the rounds (their lanes and pause updates)
    failed_views: list[str] = field(default_factory=list)
    #: recordings that left half the bit positions or more unsampled (frames lost at a steady
    #: rate, e.g. a camera fallen to half rate: an even-length word cannot be read there)
    rate_fall_views: int = 0
    rate_fall_cameras: list[str] = field(default_factory=list)  #: cameras warned of it (once each)
