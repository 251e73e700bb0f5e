"""The iron an estimator learns in operation on top of the accepted calibration (body frame): the GNSS-aided ins's
(estimator/heading_monitor.py IronLearner) or the hard iron mekf learns in turns without GNSS
(estimator/field_circle_correction.py) — kept across restarts apart from the calibration, shown, and accepted into
the calibration or reset by the operator. One store and one set of rules for both: the file says which learned
it (`source`, base.IronLearningEstimator.learned_iron_source), what, when and against which calibration.

* Persisted in the state directory as `learned_iron.json` (atomic write, calibration/atomic_file.py), tied to
  the calibration it was learned on: the key is a hash of the magnetometer model and the mounting (the learned
  offset is a body-frame field, so it only means something with both). Restored into the estimator at start
  when the key and the source match; otherwise discarded, logged and counted (`rejections`), as is a file that
  cannot be read or that the estimator refuses. A file another source learned is not overwritten until this
  estimator has learned something. Saved every SAVE_PERIOD_S when it changed, and at stop.
* Reset whenever another magnetometer calibration or mounting comes into force (`calibration_changed`).
* Shown as read-only parameters MAG_LRN_X/Y/Z (µT, body FRD) and MAG_LRN_SD (largest 1σ, µT; −1 with an
  estimator that learns none), MAG_LRN_SRC (what learned it: SOURCE_CODES, 0 while nothing is learned), and the learned soft iron I + D as MAG_LRN_S11 … MAG_LRN_S33 (row-major, body
  FRD, dimensionless) with MAG_LRN_SSD (the largest 1σ of an element of D), refreshed every PUBLISH_PERIOD_S.
* One command, CMD_LEARNED_IRON (MAV_CMD_USER_1, 31010): param1 = 1 accepts it into the calibration (the hard
  iron moves by the learned offset, then the learned one is reset), 2 resets it; the same by writing the
  momentary parameter MAG_LRN_ACT (for a ground station's parameter list). Refused while the autopilot
  reports armed (as the field calibration: TEMPORARILY_REJECTED, "Disarm to …") unless `allow_armed`.

Folding the learned offset b and soft iron I + D (body) into the calibration m_cal = W·(m_raw − h), m_body =
(I + D)⁻¹·(C·m_cal − b) (C: body←sensor mounting): C·W·(m_raw − h) − b = C·W·(m_raw − (h + W⁻¹·Cᵀ·b)), so
h' = h + W⁻¹·Cᵀ·b and W' = Cᵀ·(I + D)⁻¹·C·W. The soft iron is persisted beside the hard iron (optional keys
`soft_iron`, `soft_cov`: a file without them restores the hard iron alone).
"""

from __future__ import annotations

import hashlib
import json
import logging
import math
import time
from pathlib import Path
from typing import Callable, NamedTuple, Protocol

import numpy as np

from ahrsd.calibration.atomic_file import write_atomic
from ahrsd.calibration.models import Calibration, MagModel
from ahrsd.daemon.command_args import CommandArgs, Refused, whole_number
from ahrsd.daemon.mavlink_io import mavlink
from ahrsd.daemon.params import ParamError
from ahrsd.estimator.base import LEARNED_IN_TURNS, LEARNED_WITH_GNSS, Estimator, IronLearningEstimator

log = logging.getLogger(__name__)

FILE_NAME = "learned_iron.json"
FILE_FORMAT = "ahrsd-learned-iron"
SCHEMA_VERSION = 1
SAVE_PERIOD_S = 60.0            # a crash loses at most this much learning
PUBLISH_PERIOD_S = 1.0
CMD_LEARNED_IRON = 31010        # MAV_CMD_USER_1 (common.xml): param1 ACTION_*
ACTION_ACCEPT, ACTION_RESET = 1, 2
PARAM_NAMES = ("MAG_LRN_X", "MAG_LRN_Y", "MAG_LRN_Z", "MAG_LRN_SD")
SOFT_PARAM_NAMES = tuple(f"MAG_LRN_S{r}{c}" for r in (1, 2, 3) for c in (1, 2, 3))   # I + D, row-major
SOFT_SD_PARAM = "MAG_LRN_SSD"   # the largest 1σ of an element of D (dimensionless; −1 with none learned)
MAX_PARAM_SOFT = 10.0
ACTION_PARAM = "MAG_LRN_ACT"    # momentary: 1 accept, 2 reset (as CMD_LEARNED_IRON's param1)
NOT_LEARNING_SD = -1.0          # MAG_LRN_SD of an estimator that learns no iron
SOURCE_PARAM = "MAG_LRN_SRC"    # what learned the iron shown: 0 nothing learned, else SOURCE_CODES
SOURCE_CODES = {LEARNED_WITH_GNSS: 1, LEARNED_IN_TURNS: 2}
MAX_PARAM_UT = 1000.0


def calibration_key(calibration, mounting) -> str:
    """What a learned iron is tied to: the magnetometer model and the mounting (body←sensor DCM or None)."""
    doc = {"mag": calibration.mag.to_dict(),
           "mounting": None if mounting is None else np.round(np.asarray(mounting, float), 9).tolist()}
    return hashlib.sha256(json.dumps(doc, sort_keys=True).encode()).hexdigest()


def folded_iron(model: MagModel, mounting, offset_ut, soft_iron=None) -> MagModel:
    """The magnetometer model with the iron learned on top of it (body frame: hard iron b, soft iron I + D, the
    estimator using (I + D)⁻¹·(C·W·(m − h) − b)) folded in: W' = Cᵀ·(I + D)⁻¹·C·W, h' = h + W⁻¹·Cᵀ·b."""
    c = np.eye(3) if mounting is None else np.asarray(mounting, float)
    shift = np.linalg.solve(model.soft_iron, c.T @ np.asarray(offset_ut, float))
    a = np.eye(3) if soft_iron is None else np.asarray(soft_iron, float)
    return MagModel(model.hard_iron_ut + shift, c.T @ np.linalg.solve(a, c @ model.soft_iron))


class Learned(NamedTuple):
    """What an IronLearningEstimator has learned: the hard iron (µT, body) and its covariance (µT²), the soft iron
    I + D (dimensionless) and the covariance of D."""

    offset_ut: np.ndarray
    cov_ut2: np.ndarray
    soft_iron: np.ndarray
    soft_cov: np.ndarray

    def anything(self) -> bool:
        """A hard iron or a soft iron other than none (what is worth accepting, showing as a source, or saving over
        another source's file)."""
        return bool(np.any(np.abs(self.offset_ut) > 0.0) or np.any(self.soft_iron != np.eye(3)))


class IronPipeline(Protocol):
    """What the part reads of the per-sample path (daemon.pipeline.Pipeline), when it needs them: they are
    swapped between samples. An estimator that learns no iron (thesis) is not an IronLearningEstimator."""

    estimator: Estimator
    calibration: Calibration
    mounting: np.ndarray | None


class LearnedIron:
    """The daemon's part for the learned iron. Explicit inputs:

    state_dir: where `learned_iron.json` lives.
    pipeline: the per-sample pipeline (its `estimator`, `calibration`, `mounting`: read when needed, as they
      are swapped between samples).
    publish(name, value): shows a read-only parameter (ParamStore.show).
    statustext(severity, text), armed() -> bool, apply_calibration(cal): the daemon's hooks.
    horizontal_field_ut() -> float: WMM's horizontal field at the vehicle (NaN unknown), for the heading σ of an
      accepted iron.
    background(fn): runs a file write off the event loop (default: at once).
    """

    def __init__(self, state_dir, pipeline: IronPipeline, *, publish: Callable[[str, float], None],
                 statustext: Callable[[int, str], None], armed: Callable[[], bool],
                 apply_calibration: Callable[..., None], horizontal_field_ut: Callable[[], float] = lambda: math.nan,
                 background: Callable[[Callable[[], None]], None] | None = None, allow_armed: bool = False,
                 save_period_s: float = SAVE_PERIOD_S):
        self.path = Path(state_dir) / FILE_NAME
        self.pipeline = pipeline
        self.publish = publish
        self.statustext = statustext
        self.armed = armed
        self.apply_calibration = apply_calibration
        self.horizontal_field_ut = horizontal_field_ut
        self.background = background or (lambda fn: fn())
        self.allow_armed = allow_armed
        self.save_period_s = save_period_s
        self.key: str | None = None          # the calibration the estimator's learned iron belongs to
        self.restored = False
        self.rejections = 0                  # persisted irons dropped: another calibration or source, unreadable
        self._foreign = False                # the file holds another source's iron: kept until this one learns
        self.saves = 0
        self._saved: Learned | None = None   # what was last written
        self._next_save = -math.inf
        self._next_publish = -math.inf

    # ------------------------------------------------------------------ start / stop / periodic
    def restore(self) -> bool:
        """At start, after the estimator and calibration are in place: the persisted iron into the estimator
        when it was learned on this calibration and mounting. Never raises."""
        p = self.pipeline
        self.key = calibration_key(p.calibration, p.mounting)
        self._publish_now()
        if not isinstance(p.estimator, IronLearningEstimator):
            return False
        doc = self._read()
        if doc is None:
            return False
        if doc.get("calibration_key") != self.key:
            self._reject("was learned on another calibration or mounting")
            self._write_current()
            return False
        source = doc.get("source", LEARNED_WITH_GNSS)      # schema 1 files written before mekf learned any
        if source != p.estimator.learned_iron_source:
            self._reject(f"was learned by {source}, not by this estimator ({p.estimator.learned_iron_source})")
            self._foreign = True
            return False
        try:
            soft = doc.get("soft_iron")
            soft_cov = doc.get("soft_cov")
            p.estimator.set_learned_iron(np.asarray(doc["offset_ut"], float), np.asarray(doc["cov_ut2"], float),
                                         None if soft is None else np.asarray(soft, float),
                                         None if soft_cov is None else np.asarray(soft_cov, float))
        except (KeyError, TypeError, ValueError) as exc:
            self._reject(str(exc))
            return False
        self.restored = True
        self._saved = self._current()
        if self._saved.anything():
            log.info("learned iron restored: %s µT", np.round(self._saved.offset_ut, 2).tolist())
        else:       # the last run saved its (still zero) iron with its uncertainty: nothing learned to announce
            log.info("learned iron: nothing learned yet on this calibration")
        self._publish_now()
        return True

    def tick(self, now: float) -> None:
        """Housekeeping: refresh the parameters, save when it changed and SAVE_PERIOD_S passed."""
        if now >= self._next_publish:
            self._next_publish = now + PUBLISH_PERIOD_S
            self._publish_now()
        if now >= self._next_save:
            self._next_save = now + self.save_period_s
            if self._changed():
                payload = self._payload()
                self.background(lambda: self._write(payload))

    def save_now(self) -> None:
        """At stop: the iron learned so far (when it changed since the last save)."""
        if self._changed():
            self._write(self._payload())

    def calibration_changed(self) -> None:
        """Another calibration or mounting is in force (Service.apply_calibration, MNT_ parameters): the
        learned iron belonged to the old one; reset it. A gyro or accelerometer calibration keeps it."""
        p = self.pipeline
        key = calibration_key(p.calibration, p.mounting)
        if key == self.key:
            return
        self.key = key
        if isinstance(p.estimator, IronLearningEstimator):
            p.estimator.reset_learned_iron()
            log.info("new magnetometer calibration or mounting: learned iron reset")
        self._foreign = False                # another source's iron belonged to the old calibration too
        self._write_current()
        self._publish_now()

    # ------------------------------------------------------------------ operator actions
    def accept(self) -> tuple[bool, str]:
        """Fold the learned iron into the calibration (saved and swapped through apply_calibration), then
        reset it. Returns (done, what happened)."""
        p = self.pipeline
        est = p.estimator
        if not isinstance(est, IronLearningEstimator):
            return False, "Learned iron: this estimator learns none"
        learned = self._current()
        offset, cov, soft = learned.offset_ut, learned.cov_ut2, learned.soft_iron
        heading_sigma_rad = est.learned_iron_heading_sigma_rad()
        if not learned.anything():
            return False, "Learned iron: nothing learned yet"
        current = p.calibration
        model = folded_iron(current.mag, p.mounting, offset, soft)
        heading_std = self._accepted_heading_std_deg(current, cov, heading_sigma_rad,    # the old offset's σ is inside it
                                                     est.unmodelled_iron_ut)
        new = current.with_sensor("mag", model, method="learned-iron", heading_std_deg=heading_std,
                                  offset_std_deg=None if heading_std is None else 0.0,
                                  learned_iron_ut=offset.tolist(),
                                  learned_iron_sigma_ut=np.sqrt(np.diag(cov)).tolist(),
                                  learned_soft_iron=soft.tolist(),
                                  before={"hard_iron_ut": current.mag.hard_iron_ut.tolist(),
                                          "soft_iron": current.mag.soft_iron.tolist()})
        self.apply_calibration(new)          # the daemon's one path: persist, swap, calibration_changed()
        self.calibration_changed()           # (when the daemon's path did not call it)
        shown = " ".join(f"{v:+.1f}" for v in offset)   # as `ahrsd magcal status` shows a hard iron
        return True, f"Learned iron accepted into the calibration: hard iron {shown} uT"

    def reset(self) -> str:
        est = self.pipeline.estimator
        if isinstance(est, IronLearningEstimator):
            est.reset_learned_iron()
        self._foreign = False
        self._write_current()
        self._publish_now()
        return "Learned iron reset"

    def handle_command(self, msg, ctx=None):
        """CMD_LEARNED_IRON: param1 ACTION_ACCEPT or ACTION_RESET."""
        action = whole_number(CommandArgs.of(msg).p(1), ACTION_ACCEPT, ACTION_RESET)
        if action is None:
            return Refused(mavlink.MAV_RESULT_DENIED, "Learned iron: param1 must be 1 (accept) or 2 (reset)")
        return self.act(action)[0]

    def on_param(self, value: float) -> None:
        """MAG_LRN_ACT written (a momentary parameter, for ground stations without a command panel): 1
        accepts, 2 resets, 0 does nothing. Raises ParamError (the write is refused, with why) when refused: the
        parameter protocol's refusal is then the one STATUSTEXT that says why (not the action's as well)."""
        if value == 0:
            return
        result, text = self.act(int(value), say_refusal=False)
        if result != mavlink.MAV_RESULT_ACCEPTED:
            raise ParamError(f"MAG_LRN_ACT {value:g}: {text}")

    def act(self, action: int, *, say_refusal: bool = True) -> tuple[int, str]:
        """ACTION_ACCEPT or ACTION_RESET: (MAV_RESULT, what happened), said in a STATUSTEXT (a refusal only when
        `say_refusal`: a caller that says it itself, as a refused parameter write does, passes False)."""
        if not isinstance(self.pipeline.estimator, IronLearningEstimator):
            result, text = mavlink.MAV_RESULT_UNSUPPORTED, "Learned iron: this estimator learns none"
        elif self.armed() and not self.allow_armed:
            result, text = mavlink.MAV_RESULT_TEMPORARILY_REJECTED, "Disarm to change the learned iron"
        elif action == ACTION_RESET:
            result, text = mavlink.MAV_RESULT_ACCEPTED, self.reset()
        else:
            return self._accept_action(say_refusal)
        if result == mavlink.MAV_RESULT_ACCEPTED or say_refusal:
            self.statustext(mavlink.MAV_SEVERITY_NOTICE, text)
        return result, text

    def _accept_action(self, say_refusal: bool) -> tuple[int, str]:
        try:
            done, text = self.accept()
        except Exception as exc:  # noqa: BLE001 - the calibration in force stays (apply_calibration's contract)
            log.exception("accepting the learned iron failed")
            text = f"Learned iron: save failed: {exc}"
            if say_refusal:
                self.statustext(mavlink.MAV_SEVERITY_ERROR, text)
            return mavlink.MAV_RESULT_FAILED, text
        if done or say_refusal:
            self.statustext(mavlink.MAV_SEVERITY_NOTICE if done else mavlink.MAV_SEVERITY_WARNING, text)
        return (mavlink.MAV_RESULT_ACCEPTED if done else mavlink.MAV_RESULT_FAILED), text

    # ------------------------------------------------------------------ internals
    def _accepted_heading_std_deg(self, current, cov, iron_sigma_rad: float,
                                  unmodelled_iron_ut: float) -> float | None:
        """The heading 1σ of the calibration with the iron folded in: the old calibration's figure and the
        learned iron's (iron_sigma_rad: the estimator's, NaN unknown) in quadrature; without an old figure, the
        estimator's floor for what its learned iron does not explain (unmodelled_iron_ut over the horizontal
        field) takes its place."""
        from ahrsd.calibration.heading_trust import calibration_heading_sigma_rad

        horizontal_ut = float(self.horizontal_field_ut())
        if not (math.isfinite(horizontal_ut) and horizontal_ut > 1.0):
            return None
        # the learned iron's heading σ from its whole covariance when the estimator knows the field (with the soft
        # iron learned, the hard iron alone is poorly known on a level vehicle while their combination is not);
        # else the hard iron's horizontal σ over the horizontal field
        iron_sigma_rad = float(iron_sigma_rad)
        if not math.isfinite(iron_sigma_rad):
            iron_sigma_rad = math.sqrt(max(float(np.max(np.diag(cov)[:2])), 0.0)) / horizontal_ut
        old_sigma_rad = calibration_heading_sigma_rad(current)
        if not math.isfinite(old_sigma_rad):
            old_sigma_rad = unmodelled_iron_ut / horizontal_ut
        if not math.isfinite(old_sigma_rad):
            return None
        return math.degrees(math.hypot(old_sigma_rad, iron_sigma_rad))

    def _reject(self, why: str) -> None:
        self.rejections += 1
        log.warning("learned iron in %s dropped (%d so far): %s", self.path, self.rejections, why)

    def _current(self) -> Learned | None:
        """What the estimator has learned, None with one that learns no iron."""
        est = self.pipeline.estimator
        return Learned(*est.learned_iron(), *est.learned_soft_iron()) if isinstance(est, IronLearningEstimator) \
            else None

    def _changed(self) -> bool:
        cur = self._current()
        if cur is None or (self._foreign and not cur.anything()):
            return False
        return self._saved is None or not all(np.array_equal(a, b) for a, b in zip(cur, self._saved))

    def _publish_now(self) -> None:
        """MAG_LRN_X/Y/Z/SD, MAG_LRN_SRC and the soft iron's MAG_LRN_S11 … S33, SSD, from what is learned now."""
        cur = self._current()
        self._publish_hard_iron(cur)
        learned = cur is not None and cur.anything()
        self.publish(SOURCE_PARAM, float(SOURCE_CODES.get(self.pipeline.estimator.learned_iron_source, 0))
                     if learned else 0.0)
        self._publish_soft_iron(cur)

    def _publish_hard_iron(self, cur: Learned | None) -> None:
        if cur is None:
            values = (0.0, 0.0, 0.0, NOT_LEARNING_SD)
        else:
            values = (*(float(v) for v in cur.offset_ut), math.sqrt(max(float(np.max(np.diag(cur.cov_ut2))), 0.0)))
        for name, v in zip(PARAM_NAMES, values):
            if math.isfinite(v):
                self.publish(name, max(-MAX_PARAM_UT, min(MAX_PARAM_UT, v)))

    def _publish_soft_iron(self, cur: Learned | None) -> None:
        if cur is None:
            soft, soft_sd = np.eye(3), NOT_LEARNING_SD
        else:
            soft = cur.soft_iron
            soft_sd = math.sqrt(max(float(np.max(np.diag(cur.soft_cov))), 0.0))
            if soft_sd == 0.0 and np.array_equal(soft, np.eye(3)):
                soft_sd = NOT_LEARNING_SD       # an estimator that learns no soft iron (mekf in turns)
        for name, v in zip((*SOFT_PARAM_NAMES, SOFT_SD_PARAM), (*np.asarray(soft, float).ravel(), soft_sd)):
            if math.isfinite(v):
                self.publish(name, max(-MAX_PARAM_SOFT, min(MAX_PARAM_SOFT, float(v))))

    def _payload(self) -> bytes:
        cur = self._current()
        self._saved = Learned(*(a.copy() for a in cur))
        doc = {"format": FILE_FORMAT, "schema_version": SCHEMA_VERSION, "calibration_key": self.key,
               "source": self.pipeline.estimator.learned_iron_source,
               "offset_ut": cur.offset_ut.tolist(), "cov_ut2": cur.cov_ut2.tolist(), "soft_iron": cur.soft_iron.tolist(),
               "soft_cov": cur.soft_cov.tolist(),
               "wall_time_s": time.time()}    # host clock: when it was saved, read across reboots
        return (json.dumps(doc, indent=1) + "\n").encode()

    def _write_current(self) -> None:
        if self._current() is not None:
            self._write(self._payload())

    def _write(self, data: bytes) -> None:
        try:
            write_atomic(self.path, data, mode=0o644)
            self.saves += 1
        except OSError as exc:
            log.warning("cannot save the learned iron: %s", exc)

    def _read(self) -> dict | None:
        try:
            doc = json.loads(self.path.read_text())
        except FileNotFoundError:
            return None
        except (OSError, ValueError) as exc:
            self._reject(str(exc))
            return None
        if not isinstance(doc, dict) or doc.get("format") != FILE_FORMAT or doc.get("schema_version") != SCHEMA_VERSION:
            self._reject(f"not an ahrsd learned-iron file of schema {SCHEMA_VERSION}")
            return None
        return doc
