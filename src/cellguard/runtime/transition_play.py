"""Playing the safe transitions of a run: the approach to the policy's first target and the retreat home,
one servo period at a time through the guard's link, aborted by a stop as its category asks.

``TransitionPlay`` is a part of ``loop.Run`` (its base): it reads and writes the run's clock, guard, link, events
and stop state, and ``Run`` gives it ``_send``, ``_operator_stop``, ``_without_link`` and the power-off reasons. The
plans themselves (ruckig, the box check) are ``transitions.Transition``'s.
"""

from __future__ import annotations

import numpy as np

from cellguard.control.events import Event, EventKind
from cellguard.robot.protocol import SafetyInputs
from cellguard.runtime.transitions import Transition, speed_cap


class TransitionPlay:
    """The approach's and the retreat's playing, for ``loop.Run``."""

    def retreat(self) -> None:
        """At the end of the run (or after a stop with power kept): back to the home pose, unless its path would take
        the tool out of the workspace box: then the robot holds where it stopped and the run ends stopped."""
        if not self.guard.power:  # a category 0/1 stop in the last cycle: no reset follows, the run ends stopped
            self.stopped = self.stopped or self._power_removed(self.guard.envelope)  # (it ended clean, exit 0: no more)
            return
        home = getattr(self.cell, "q_home", None)
        unrecorded = self.recording is not None and self.recording.failed  # no motion the record would not hold
        if home is None or self.link.stop is not None or unrecorded:  # a link fault too
            return
        if self.recovery is not None and self.recovery.held_at_end:  # someone may be in the cell: no motion
            self.events.append(Event(self.clock.now(), EventKind.RETREAT_ABORTED, "retreat not played: the run "
                                     "stopped during an operator's hand-over hold; the robot stays where it is held"))
            return
        plan = self._way_home(home, self._commanded_motion())
        first, signals = self.events.total, min(self.operator.count, 1)  # the operator's first signal stopped the
        # run (or ends it now); a second aborts this
        begun = plan is not None and plan.brakes and not plan.settles
        if plan is not None and plan.brakes:  # the command still moves (a time cycle ended mid-motion): to rest
            # first, then the way home checked from there (checked first, the moving command held its setpoint the
            # 15 to 100 ms the check took: a dead stop)
            if begun:
                self._begin(plan, "retreat", self.clock.now())
            self._play(plan.braking(), "retreat", self.clock.now(), signals=signals)
            if self._retreat_ended(first, signals):
                return
            plan = self._way_home(home, {})  # at rest where the brake left it (the guard's state is from before)
        if plan is None:
            return
        outside = self._leaves_box(plan)
        self.clock.regrid()  # the way home planned and checked at rest (15 to 100 ms): a pause, no late tick
        if outside is not None:  # not played: the robot holds where it stopped, at rest
            self._retreat_not_played(outside, begun)
            return
        self._play(plan, "retreat", self.clock.now(), signals=signals, begun=begun)
        self._retreat_ended(first, signals)

    def _retreat_not_played(self, outside: str, braked: bool) -> None:
        """The way home (beyond the brake that brought the command to rest: ``braked``) would take the tool out of the
        box (``outside``): not played, the robot holds where it stopped and the run ends stopped."""
        played = " beyond its brake" if braked else ""
        self.events.append(Event(self.clock.now(), EventKind.RETREAT_ABORTED, f"retreat not played{played}: "
                                 f"{outside}; the robot holds where it stopped"))
        self.stopped = self.stopped or (f"the retreat home was not played{played}: {outside}; the robot is held where "
                                        "it stopped, power on: bring it home before the next run")

    def _way_home(self, home, motion: dict) -> Transition | None:
        """The retreat's plan from the command, moving as ``motion`` says (``_commanded_motion``; {}: at rest), to
        ``home``, or None where it is there at rest."""
        return Transition.plan(self.cell.profile, self.link.last_sent, np.asarray(home), self.clock.period_ns,
                               **motion, **self._cap(self.cell.safety()))

    def _retreat_ended(self, first: int, signals: int) -> bool:
        """Did a stop end the retreat played since event ``first``: the run then ends stopped (a category 0/1 stop:
        no reset follows; a category 2 pulse: away from home, where the run ended clean before)."""
        if not self.guard.power:
            self.stopped = self.stopped or self._power_removed(self.guard.envelope)
        elif any(e.kind == EventKind.RETREAT_ABORTED for e in self.events.since(first)):
            self.stopped = self.stopped or self._retreat_aborted(signals)
        else:
            return False
        return True

    def _leaves_box(self, plan: Transition) -> str | None:
        """Where ``plan`` would take the tool out of the guard's workspace box (``Transition.leaves_box``), or None."""
        return plan.leaves_box(self.cell.profile, self.guard.tool, self.guard.config.box, self._reach)

    def _retreat_aborted(self, signals: int) -> str:
        """Why the run ended with its retreat aborted by a category 2 stop: the operator's signal (its own words,
        which the command reads as an operator stop), a robot link fault, else the safety controller's input,
        which holds the robot where it braked."""
        if self.operator.count > signals:
            return self.operator.reason
        if self.link.stop is not None:
            return f"robot link: {self.link.reason}"
        return ("the retreat was aborted by a category 2 stop: the robot is held where it braked, not at home, power "
                "on; bring it home before the next run")

    def _commanded_motion(self) -> dict:
        """The command's velocity and acceleration now (the guard's setpoints'), where a transition starts: a
        cycle that ended mid-motion is braked first, never stopped dead."""
        tracker = self.guard.envelope.tracker
        _, v, a = tracker.samples
        half_dt = 0.5 * tracker.dt
        return {"velocity": [x + y * half_dt for x, y in zip(v, a)], "acceleration": a}

    def _cap(self, safety: SafetyInputs) -> dict:
        """The guard's tool-speed cap in force with these inputs (``transitions.speed_cap``), the tool's reach, its
        model and the workspace box: what a transition goes under (slower where its brakes would leave the box)."""
        return {"cap": speed_cap(self.guard.config, safety), "reach": self._reach, "box": self.guard.config.box,
                "tool": self.guard.tool}

    def _play(self, plan: Transition, name: str, t0: int, signals: int | None = None, begun: bool = False
              ) -> np.ndarray:
        """Play a transition tick by tick; return the pose it left the robot at. A stop input, a link fault or
        an operator's signal past ``signals`` (default: those so far) aborts it as the stop's category asks
        (``_ticks``); a category 0 or 1 stop then removes power through the guard, where the brake left the robot.
        A plan that only settles the command is not told as a transition (every run's last cycle ended with its
        command a few ms from rest). ``begun``: its begin was told already (``_begin``: a retreat from motion, told with
        its brake)."""
        signals = self.operator.count if signals is None else signals
        if not plan.settles and not begun:
            self._begin(plan, name, t0)
        with self.clock.ticking():
            held, stop = self._ticks(plan, name, signals)
            if stop is not None and stop[0] < 2:
                self.guard.reset(held)  # where the transition left the robot
                self._remove_power(stop, signals)
        if stop is None and not plan.settles:
            self.events.append(Event(self.clock.now(), EventKind(f"{name}_done"), f"{name} complete"))
        self._at_rest()
        return held

    def _begin(self, plan: Transition, name: str, t_ns: int) -> None:
        """The transition's ``*_begin`` event: how long it takes, and where to."""
        self.events.append(Event(t_ns, EventKind(f"{name}_begin"),
                                 f"{name}: {plan.duration_s:.2f} s to {np.round(plan.target, 3).tolist()}"))

    def _at_rest(self) -> None:
        """The command is at rest (a transition played or braked, the run's end): a stop signal that insisted during
        the brake raises KeyboardInterrupt now (``OperatorStop.at_rest``), the record saying so first."""
        operator = self.operator
        if operator.waiting:
            self.events.append(Event(self.clock.now(), EventKind.OPERATOR_STOP, f"{operator.signal}: {operator.count} "
                                     f"stop signals, {operator.waiting} of them during the brake: KeyboardInterrupt, "
                                     "held until the command came to rest"))
        operator.at_rest()

    def _ticks(self, plan: Transition, name: str, signals: int) -> tuple[np.ndarray, tuple[int, str | None] | None]:
        """The transition's setpoints, one per servo period; return the last one sent and the stop that aborted
        it, (category, who asked: None for the safety controller), if one did. A category 0 stop sends nothing
        more (power goes at once); 1 and 2 brake to a standstill under the profile's limits (stopping the
        setpoints dead at full speed stepped the command 63 mrad in one 1 ms tick). A reduced-speed input that
        comes on replans the rest under its cap (``_slow_down``)."""
        profile, rec, held = self.cell.profile, self.recording, plan.start
        for steps, setpoint in enumerate(plan.setpoints()):
            t = self.clock.now()
            safety = self.cell.safety()
            stop = self._transition_stop(t, safety, signals)
            if stop is not None:
                self._aborted(t, name, stop)
                return self._brake(None if stop[0] == 0 else plan.brake(profile, steps), name, held, stop, signals)
            if safety.reduced_speed and plan.cap > self.guard.config.reduced_speed:  # it comes on: once, off the
                # other ticks (the cap is worked out from the guard's checks)
                slower = plan.slowed(profile, steps, **self._cap(safety))
                if slower is not None:
                    self.events.append(Event(t, EventKind.REDUCED_SPEED_INPUT, f"safety controller reduced-speed "
                                             f"input: the {name} slows down, {slower.duration_s:.2f} s to go"))
                    return self._slow_down(slower, name, signals)
            held = self._send([setpoint], rec)
        return held, None

    def _slow_down(self, slower: Transition, name: str, signals: int
                   ) -> tuple[np.ndarray, tuple[int, str | None] | None]:
        """The rest of a transition a reduced-speed input slowed (``Transition.slowed``), as ``_ticks``: its brake,
        then its new way on from rest there, kept in the box (slower where its brakes would leave it) and checked
        against it first (played unchecked, it took the tool up to 9 mm out; checked before the brake, the moving
        command would hold its setpoint the 5 to 150 ms the check takes). A way on that leaves the box is not
        played, as a transition's that does from the start: the approach refuses the start, the retreat ends the run
        stopped, the robot held where it braked (returned as a category 2 stop)."""
        brake = slower.braking()
        held, stop = (slower.start, None) if brake is None else self._ticks(brake, name, signals)
        rest = None if stop is not None else slower.after_braking()
        if rest is None:
            return held, stop
        if brake is not None:  # planned from motion: kept in the box from rest here (``Transition.plan``)
            rest = rest.kept_in_box(self.cell.profile, self.guard.tool, self.guard.config.box, self._reach)
        outside = self._leaves_box(rest)
        self.clock.regrid()  # that check, at rest, is no late tick
        if outside is None:
            return self._ticks(rest, name, signals)
        if name == "approach":
            self._refuse(f"start-up: the approach to the first target {np.round(rest.target, 3).tolist()}, slowed "
                         f"down by the reduced-speed input: {outside}; " + ("not moving" if brake is None else
                                                                           "held where it braked"))
        self._retreat_not_played(outside, braked=brake is not None)
        return held, (2, "the workspace box")

    def _brake(self, brake: Transition | None, name: str, held: np.ndarray, stop: tuple[int, str | None],
               signals: int) -> tuple[np.ndarray, tuple[int, str | None]]:
        """An aborted transition's brake (None: none), one servo period at a time, the stops read every tick as
        before the abort: a stricter one counts from its tick, category 0 sending nothing more (it went on braking
        to the end, and a category 0 input after a category 2 abort never removed power). Return the last
        setpoint sent and the strictest stop."""
        for setpoint in () if brake is None else brake.setpoints():
            held = self._send([setpoint], self.recording)
            t = self.clock.now()
            asked = self._transition_stop(t, self.cell.safety(), signals, stop)
            if asked[0] < stop[0]:
                stop = asked
                self._aborted(t, name, stop)
                if stop[0] == 0:
                    break
        return held, stop

    def _aborted(self, t_ns: int, name: str, stop: tuple[int, str | None]) -> None:
        """The transition's ``*_aborted`` event for ``stop``: the abort, and each stricter stop during its brake."""
        why = stop[1] or "the safety controller's protective stop input"
        self.events.append(Event(t_ns, EventKind(f"{name}_aborted"), f"{why}: a category {stop[0]} stop during the "
                                 "transition", category=stop[0]))

    def _transition_stop(self, t_ns: int, safety: SafetyInputs, signals: int,
                         since: tuple[int, str | None] | None = None) -> tuple[int, str | None] | None:
        """The strictest stop asked during a transition: ``since`` (one asked before, still in force), the safety
        controller's input, a robot link fault, an operator's signal past ``signals``; (category, who asked: None
        for the controller) or None; a lost link makes a category 1 or 2 stop a 0 (``_without_link``)."""
        asked = [] if safety.stop is None else [(safety.stop, None)]
        if since is not None:
            asked.append(since)
        if self.link.stop is not None:
            asked.append((self.link.stop, f"robot link, {self.link.reason}"))
        if self.operator.count > signals:
            self._operator_stop(t_ns)
            asked.append((EventKind.OPERATOR_STOP.category, self.operator.reason))
        return self._without_link(min(asked, key=lambda a: a[0], default=None))

    def _remove_power(self, stop: tuple[int, str | None], signals: int) -> None:
        """Drive power off by the guard's own stop, as on the cycles' ticks: at once for category 0, for category 1
        once the guard finds the machine stopped (it holds meanwhile, reading the robot every tick). The stops
        are read every tick meanwhile: a stricter one counts at once (``_transition_stop``)."""
        rec = self.recording
        while True:
            t = self.clock.now()
            stop = self._transition_stop(t, self.cell.safety(), signals, stop)
            setpoint, new = self.guard.tick(t, self.link.state, SafetyInputs(stop[0], False, stop[1]))
            self.events.extend(new)
            if not self.guard.power:
                self._power_off(t)
                return
            self._send([setpoint], rec)
