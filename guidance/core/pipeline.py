"""The in-car core as a pure, message-driven object: timestamped messages in, outputs out.

``Pipeline.feed(msg)`` takes one input (wheel odometry, compass reading, heading fix,
landmark fix, intersection scene, turn report, cancel of the last report, new goal, a driver's
status flip) and returns what it caused: decisions, prompts, landmark updates, turns, health
changes, and the state when it is due. No I/O, no clock reads, no asyncio: the time is the
message's ``t_s``. The live app (``guidance.app``), the accelerated simulation
(``hal_sim.drive``), replay (``guidance.tools.replay``) and the tests all drive this same
object, so they compute the same thing.

It is a sequencer of the core's two stages (``../shared/ARCHITECTURE-3.md`` section 5), in the
order of the reference trial (``hal_sim.reference``)::

    step = self.localizer.handle(msg)        # the estimator: every estimate the input made
    plan = self.planner.handle(msg, step)    # mode, lost / arrival, decisions, prompts
    self._health(...)                        # the inputs' liveness and verdicts

``snapshot``/``restore`` give the whole state as plain data (checkpoints).
"""

from __future__ import annotations

import logging
import math
from collections import Counter
from collections.abc import Mapping
from dataclasses import asdict

from guidance.core import speech
from guidance.core.health import BAD_STATUSES, DeviceStatus, HealthMonitor
from guidance.core.localize.localizer import Localizer, LocalizerConfig
from guidance.core.localize.state_limits import state_problem
from guidance.core.messages import (
    EstimateState,
    GoalUpdate,
    Health,
    Priority,
    Prompt,
    Say,
    Speech,
    Target,
)
from guidance.core.pipeline_config import (
    INPUT_KINDS,
    Input,
    Outputs,
    PipelineConfig,
    planner_config,
)
from guidance.core.pipeline_state import LocalizeState, PipelineState, PlanState
from guidance.core.plan.navigator import Decision, Navigator
from guidance.core.plan.planner import Planner
from guidance.core.snapshot_check import check_snapshot

log = logging.getLogger(__name__)

HEALTH_EVAL_PERIOD_S = 0.25
"""Health is re-evaluated at most this often on the message clock."""


class Pipeline:
    """Localizer, then planner, then health, driven by messages (see module doc)."""

    def __init__(self, config: PipelineConfig) -> None:
        self.config = config
        self.counts: Counter[str] = Counter()
        """One table for the three parts' counts (a checkpoint's ``counts``)."""
        self.health = HealthMonitor(config.expected_rates_hz, config.health)
        self.localizer = Localizer(LocalizerConfig.of(config), self.health, self.counts)
        self.planner = Planner(planner_config(config), self.counts)
        self.st = PipelineState()
        self._last_t: float | None = None
        self._next_health_t = -math.inf

    # -- the one entry point ----------------------------------------------------------------
    def feed(self, msg: Input) -> Outputs:
        """Apply one timestamped input and return what it caused."""
        out = Outputs()
        t = msg.t_s
        if not math.isfinite(t):
            out.accepted, out.reason = False, "non_finite_time"
            self.counts["rejected"] += 1
            return out
        self.counts[type(msg).__name__] += 1
        self.health.observe(INPUT_KINDS.get(type(msg), "other"), t)
        if self._last_t is None or t > self._last_t:
            self._last_t = t
        if self.planner.st.finished and not isinstance(msg, GoalUpdate):
            out.accepted, out.reason = False, "finished"
        elif isinstance(msg, DeviceStatus):
            self._device_status(msg, out)
        else:
            step = self.localizer.handle(msg)
            out = self.planner.handle(msg, step)
            if step.accepted is not None:  # a sensor input: the filter's verdict
                out.accepted, out.reason = step.accepted, step.reason
        self._health(t, out, force=False)
        self.st.prompt_count += len(out.prompts)
        return out

    def tick(self, t_s: float) -> Outputs:
        """Time passes with no input (a silent car): health only; the estimate is untouched."""
        out = Outputs()
        if math.isfinite(t_s):
            self._health(t_s, out, force=True)
        self.st.prompt_count += len(out.prompts)
        return out

    def camera_seen(self, t_s: float) -> None:
        """A camera frame arrived (its liveness; the frame itself goes to the recogniser)."""
        self.health.observe("camera", t_s)

    def update_source_counts(self, name: str, read: int, rejected: int) -> None:
        """Feed a source's cumulative read/rejected counts (garbled-input detection)."""
        self.health.update_counts(name, read, rejected)

    # -- health ---------------------------------------------------------------------------------
    def _device_status(self, msg: DeviceStatus, out: Outputs) -> None:
        """A driver's status flip: the input's sentence for that status is what the driver
        hears ("Wheel speed bus disconnected. Position is getting less certain."), once per
        episode, whether the driver or the pipeline's clock noticed first."""
        went_bad = self.health.report(msg)
        if went_bad and msg.input not in self.st.warned:
            self.st.warned.append(msg.input)
            say = Say(Speech.SENSOR, input=msg.input, status=msg.health.status)
            out.prompts.append(self._prompt(msg.t_s, say))
        self._health(msg.t_s, out, force=True)

    def _prompt(self, t: float, say: Say) -> Prompt:
        """A sensor prompt, worded by the table (``speech.words``, ``[navigation] units``)."""
        text = speech.words(say, self.config.units)
        return Prompt(t, text, Priority.SAFETY, speech.kind(say), say)

    def _health(self, t: float, out: Outputs, force: bool) -> None:
        if not force and t < self._next_health_t:
            return
        self._next_health_t = t + HEALTH_EVAL_PERIOD_S
        judge = self.localizer.compass_judge
        for change in self.health.evaluate(t):
            out.health.append(change)
            st = change.status
            if st.alive and st.valid:
                if st.name in self.st.warned:
                    self.st.warned.remove(st.name)
                log.warning("%s is back (%.1f Hz)", st.name, st.rate_hz)
                continue
            problem = "is silent" if not st.alive else "sends bad data"
            bad = "silent" if not st.alive else "invalid"
            status = st.status if st.status in BAD_STATUSES else bad
            judged = st.name == "compass" and st.alive and judge.unusable
            if judged:  # its readings arrive and parse; the filter rejects most of them
                log.warning("compass is unusable (%s): the filter rejected most of its "
                            "readings over the last %.0f s; steering without it",
                            judge.reason, judge.window_s)  # fmt: skip
            else:
                log.warning("%s %s: %s", st.name, problem, st.detail)
            if st.name in self.st.warned:
                continue  # one warning per input and episode (its driver may have said it)
            self.st.warned.append(st.name)
            say = Say(Speech.SENSOR, input=st.name, status=status)
            if judged:
                say = Say(Speech.COMPASS_UNUSABLE, status=judge.reason)
            out.prompts.append(self._prompt(t, say))

    # -- views ----------------------------------------------------------------------------------
    @property
    def t_s(self) -> float | None:
        return self._last_t

    @property
    def estimate(self) -> EstimateState:
        """The estimate now, with the distance driven, the speed and whether the heading is
        known: one frozen value (the filter itself stays inside ``core/localize``)."""
        return self.localizer.estimate()

    def state(self) -> EstimateState:
        return self.localizer.estimate()

    @property
    def arrived(self) -> bool:
        """The car has been told it has arrived (until a new goal)."""
        return self.planner.st.arrived

    @property
    def finished(self) -> bool:
        """Guidance has ended (``stop_at_arrival``: arrived, or lost with no way back)."""
        return self.planner.st.finished

    @property
    def lost(self) -> bool:
        """The car has been told it is lost (until it is found again)."""
        return self.planner.st.lost_said

    @property
    def landmark_updates(self) -> int:
        """Landmark fixes the filter took so far."""
        return self.localizer.st.landmark_updates

    @property
    def navigator(self) -> Navigator:
        return self.planner.navigator

    @property
    def searching(self) -> bool:
        """The car is lost and can find itself again (``PipelineConfig.relocalise``): a place
        recognised now is a whole-database find (``LandmarkFix.relocalised``)."""
        return self.config.relocalise and self.planner.st.lost_said

    def target(self) -> Target | None:
        """What the car aims at now (None: no goal)."""
        return self.planner.target(self.localizer.estimate())

    @property
    def last_decision(self) -> Decision | None:
        """The latest decision made (for any intersection ahead)."""
        return self.planner.guide.last_decision

    @property
    def reports(self) -> int:
        """Intersection reports taken so far (each ``Ahead.seq``)."""
        return self.planner.guide.reports

    @property
    def last_report_seq(self) -> int:
        """The report number of the intersection the last report was about."""
        return self.planner.guide.last_seq

    def planned_exit(self, seq: int) -> int | None:
        """The exit planned now for intersection report ``seq`` (None: not decided yet)."""
        return self.planner.guide.planned_exit(seq)

    def statuses(self, t_s: float) -> dict[str, Health]:
        """Each input's health now (the health message carries them as they are)."""
        return self.health.statuses(t_s)

    # -- checkpoints ----------------------------------------------------------------------------
    def snapshot(self) -> dict[str, object]:
        """The whole state as JSON-able data (estimator, navigator memory, bookkeeping)."""
        return {
            **self.localizer.snapshot(),
            **self.planner.snapshot(),
            **asdict(self.localizer.st),
            **asdict(self.st),
            "counts": dict(self.counts),
        }

    def restore(self, snap: Mapping[str, object], *, same_clock: bool = True) -> None:
        """Put the pipeline back where ``snapshot`` left it (after a crash).

        ``same_clock``: the message clock continues from the snapshot's (the simulation, a
        restart within one boot); False for the car in general, where the monotonic clock
        may have restarted with the laptop, so the snapshot's times are not carried over.
        Every value is checked first (``snapshot_check``): a bad one raises ``SnapshotError``
        and nothing is changed.
        """
        nav = self.planner.navigator
        check_snapshot(
            snap,
            n_state=self.localizer.state_size,
            start_xy=self.config.start_xy_m,
            n_landmarks=len(nav.landmarks),
            mem_capacity=nav.config.max_intersections,
            mem_width=nav.config.max_exits,
            state_problem=state_problem,
            prior_variances=self.localizer.prior_variances(),
        )
        # every state checked too, before anything changes
        loc_st = LocalizeState.from_snapshot(snap)
        plan_st = PlanState.from_snapshot(snap)
        st = PipelineState.from_snapshot(snap)
        last = snap.get("last_t_s") if same_clock else None
        same_t = float(last) if isinstance(last, int | float) else None
        if not same_clock:
            plan_st.landmark_said.clear()  # message times of another clock
        self.localizer.restore(snap, loc_st, same_t)
        self.planner.restore(snap, plan_st)
        self.st = st
        self._next_health_t = -math.inf
        counts = snap.get("counts", {})
        if isinstance(counts, dict):  # in place: the stages count into the same table
            self.counts.clear()
            self.counts.update({str(k): int(v) for k, v in counts.items()})
        self._last_t = same_t
