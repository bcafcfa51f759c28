"""The curated mutations: each disables or weakens one safety check the README promises.

``old`` must occur exactly once in ``path`` (and each of ``also``'s in its own); ``tests`` are the tests that guard the check (node ids
relative to the repository root), run with ``-x``. A mutation that no test kills is a safety
claim without a test.
"""

from __future__ import annotations

from dataclasses import dataclass

PROPS = "tests/test_envelope_properties.py"
ENV = "tests/test_envelope.py"
EXE = "tests/test_executor.py"
GUARD = "tests/test_guard.py"
LIM = "tests/test_guard_limits.py"
POSITION = f"{LIM}::test_a_reference_past_the_hard_limits_stops_inside_the_soft_ones"
OVER = f"{LIM}::test_a_reference_over_one_derivative_limit_is_brought_inside"
LIMITS = f"{PROPS}::test_setpoints_never_exceed_the_limits"
STOP = f"{LIM}::test_a_stop_from_speed_reaches_zero_velocity_within_its_bound"
STOPS = f"{PROPS}::test_every_stop_reaches_zero_velocity_within_its_bound"
TRACKER = "src/cellguard/control/tracker.py"
ENVELOPE = "src/cellguard/control/envelope.py"
STOP_POWER = "tests/test_stop_power.py"
CHECKS = "src/cellguard/control/checks"
EXECUTOR = "src/cellguard/control/executor.py"
WORKSPACE = "tests/test_workspace.py"
BOX_INSIDE = f"{WORKSPACE}::test_a_reference_inside_the_box_is_followed_without_leaving_it"
BOX_LEAVES = f"{WORKSPACE}::test_a_stop_for_a_reference_that_leaves_the_box_ends_inside_it"
BOX_BACK_IN = f"{WORKSPACE}::test_a_tool_found_outside_the_box_comes_back_in_without_a_stop"
BOX_RANDOM = f"{WORKSPACE}::test_random_chunks_never_take_the_tool_out_of_the_box"
BOX_TURNING = f"{WORKSPACE}::test_a_joint_whose_stop_is_said_not_to_turn_back_moves_one_way"
BOX_MARGIN = f"{WORKSPACE}::test_the_travel_between_two_samples_is_never_less_than_their_gaps"
PER_WALL = "tests/test_box_per_wall.py"
BOX_SIDE_WALL = f"{PER_WALL}::test_a_guarded_swing_from_over_the_ceiling_stops_at_the_side_wall"
BOX_NO_CREEP = f"{PER_WALL}::test_stops_between_chunks_do_not_let_a_tool_outside_the_box_creep_further_out"
REAL_TIME_CAP = f"{ENV}::test_a_speed_cap_holds_the_sent_setpoints_of_a_policy_that_answers_in_real_time"
SOFT_5MS = f"{LIM}::test_a_joint_stops_inside_its_soft_limits_at_a_5_ms_servo_period"
SPEEDS_UP = f"{LIM}::test_a_reference_that_speeds_up_past_the_velocity_limit_is_held_at_it"
INWARD = "tests/test_tracker_inward.py"
STALE = "tests/test_stale_standstill.py"


@dataclass(frozen=True)
class Mutation:
    name: str
    check: str  # the promise it breaks
    path: str
    old: str
    new: str
    tests: tuple[str, ...]
    also: tuple[tuple[str, str, str], ...] = ()  # further (path, old, new) edits of the same mutation


MUTATIONS = (
    Mutation("position_lookahead_off", "position soft limit: stopping-distance look-ahead", TRACKER,
             "fit = self._stop_fits(j, qj, v_end, a, qj + far > hi, qj - far < lo)", "fit = fit",
             (POSITION, LIMITS, SOFT_5MS)),
    Mutation("position_lookahead_wrong_side", "position soft limit: the look-ahead checks the limit it nears",
             TRACKER, "fit = self._stop_fits(j, qj, v_end, a, qj + far > hi, qj - far < lo)",
             "fit = self._stop_fits(j, qj, v_end, a, qj - far < lo, qj + far > hi)", (POSITION, LIMITS, SOFT_5MS)),
    Mutation("outside_frozen", "position: a joint past its soft limit comes back inward", TRACKER,
             "<= max(self._hi_f[j], min(q, p))", "<= self._hi_f[j]",
             (f"{INWARD}::test_a_joint_reset_past_its_soft_limit_follows_a_reference_back_inside",),
             also=((TRACKER, ">= min(self._lo_f[j], max(q, p))", ">= self._lo_f[j]"),)),
    Mutation("outside_moves_out", "position: a joint past its soft limit never goes further out", TRACKER,
             "<= max(self._hi_f[j], min(q, p))", "<= max(self._hi_f[j], q + 1.0)",
             (f"{INWARD}::test_a_joint_past_its_soft_limit_never_moves_further_out",),
             also=((TRACKER, ">= min(self._lo_f[j], max(q, p))", ">= min(self._lo_f[j], q - 1.0)"),)),
    Mutation("soft_margin_zero", "position: soft limits inside the hard limits", ENVELOPE,
             "*profile.soft_limits(c.soft_margin)", "*profile.soft_limits(0.0)", (POSITION,)),
    Mutation("recovery_ignores_position", "position: the recovery brakes and aims inside the soft limits", TRACKER,
             "t = min(max(x, lo), hi)", "t = x",
             (POSITION, LIMITS),
             also=((TRACKER, "if not self._stop_clears(j, nq[j], nv[j], na[j]):", "if False:"),)),
    Mutation("velocity_limit_x10", "velocity limit", TRACKER,
             "np.stack([self.v_max, self.a_max, self.j_max])", "np.stack([self.v_max * 10, self.a_max, self.j_max])",
             (f"{OVER}[velocity]", LIMITS, SPEEDS_UP)),
    Mutation("acceleration_limit_x10", "acceleration limit", TRACKER,
             "np.stack([self.v_max, self.a_max, self.j_max])", "np.stack([self.v_max, self.a_max * 10, self.j_max])",
             (f"{OVER}[acceleration]", LIMITS)),
    Mutation("jerk_limit_infinite", "jerk limit (pass-through)", TRACKER,
             "np.stack([self.v_max, self.a_max, self.j_max])", "np.stack([self.v_max, self.a_max, self.j_max * np.inf])",
             (f"{OVER}[jerk]", LIMITS)),
    Mutation("ruckig_jerk_x1000", "jerk limit (ruckig)", TRACKER,
             "inp.max_velocity, inp.max_acceleration, inp.max_jerk = self.v_max, self.a_max, self.j_max",
             "inp.max_velocity, inp.max_acceleration, inp.max_jerk = self.v_max, self.a_max, self.j_max * 1000",
             (f"{OVER}[jerk]", f"{OVER}[acceleration]", STOP)),
    Mutation("effort_off", "effort limit", f"{CHECKS}/effort.py",
             "        if state is None:\n            return None", "        if True:\n            return None",
             (f"{PROPS}::test_an_effort_stop_follows_exactly_from_the_measured_efforts",)),
    Mutation("effort_hold_x3", "effort limit: hold time", f"{CHECKS}/effort.py",
             "self._hold = _hold_samples(hold_s, dt_ns)", "self._hold = 3 * _hold_samples(hold_s, dt_ns)",
             (f"{PROPS}::test_an_effort_stop_follows_exactly_from_the_measured_efforts",)),
    Mutation("box_off", "tool box", f"{CHECKS}/__init__.py",
             "        after.append(WorkspaceLookahead(c.box, profile, tool, tracker))", "        pass",
             (f"{ENV}::test_workspace_box_stops_before_the_tool_leaves_it", BOX_INSIDE)),
    Mutation("box_lookahead_off", "tool box: look-ahead along the stop's path", f"{CHECKS}/workspace.py",
             "        plan = tracker.stop_plan()\n        if plan is None:",
             "        return _inside(tip, lo, hi, 0.0)\n        plan = tracker.stop_plan()\n        if plan is None:",
             (f"{ENV}::test_workspace_box_stops_before_the_tool_leaves_it", BOX_INSIDE, BOX_LEAVES)),
    Mutation("box_path_margin_off", "tool box: the path between the stop's samples", f"{CHECKS}/workspace.py",
             "return 0.5 * (sum(w * abs(y - x) for w, x, y in zip(self._weight, a, b)) + self._turned[j] - self._turned[i])",
             "return 0.0", (BOX_INSIDE, BOX_LEAVES, BOX_RANDOM)),
    Mutation("box_turning_off", "tool box: a joint whose stop turns back", TRACKER,
             "return StopPlan(plan.duration, lambda t: plan.at_time(t)[0], turning)",
             "return StopPlan(plan.duration, lambda t: plan.at_time(t)[0], ())", (BOX_TURNING, BOX_MARGIN)),
    Mutation("limit_screen_off", "soft limits: the loose screen of a recovered joint's stop", TRACKER,
             "if -a_max <= a <= a_max and self._lo_f[j] <= q - far and q + far <= self._hi_f[j]:", "if True:",
             (POSITION, SOFT_5MS, LIMITS)),
    Mutation("box_excursion_refused", "tool box: a tool found outside may come back in", f"{CHECKS}/workspace.py",
             "return None if self._grown and self._end_fits(tracker) else STOP", "return STOP", (BOX_BACK_IN,)),
    Mutation("box_every_wall_grown", "tool box: from outside, a wall the tool is inside of stays a wall",
             f"{CHECKS}/workspace.py",
             "out_hi = tuple(float(p) + SLACK if p > b else float(b) for p, b in zip(point, hi))",
             "out_hi = tuple(float(b) + (max(q - c for q, c in zip(point, hi)) + SLACK if any(q > c for q, c in "
             "zip(point, hi)) else 0.0) for b in hi)", (BOX_SIDE_WALL,)),
    Mutation("box_regrown_at_stops", "tool box: from outside, a stop lets the tool no further out",
             f"{CHECKS}/workspace.py", "if self._still or (tick.stop_kind is not None and self._grown is None):",
             "if self._still or tick.stop_kind is not None:", (BOX_NO_CREEP,)),
    Mutation("box_resume_flood", "tool box: no stop flood where the way on leads out", f"{CHECKS}/workspace.py",
             "return None if _depth(tool(step).tolist(), lo, hi) > depth else STOP", "return None",
             (BOX_LEAVES,)),
    Mutation("tool_speed_cap_off", "tool speed cap", f"{CHECKS}/tool_speed.py",
             "        return self._cap", "        return None",
             (f"{ENV}::test_tool_speed_cap_holds_in_normal_operation",)),
    Mutation("reduced_speed_input_off", "reduced speed (safety controller input)", f"{CHECKS}/safety_input.py",
             "return self._cap if tick.safety.reduced_speed else None", "return None",
             (f"{ENV}::test_reduced_speed_input_caps_the_tool_speed_and_keeps_the_path",)),
    Mutation("tool_speed_cap_tracker_off", "tool-speed cap: the sent setpoints, not just the playback clock",
             ENVELOPE, "setpoint = tracker.follow(reference, tool_cap)", "setpoint = tracker.follow(reference)",
             (REAL_TIME_CAP, f"{PROPS}::test_the_reduced_speed_input_caps_the_tool_speed_on_every_stream")),
    Mutation("reduced_speed_ignores_tool_speed", "reduced speed: cap on the tool speed ahead", ENVELOPE,
             "target = min(1.0, 0.9 * cap.cap / speed)", "target = min(1.0, 0.9 * cap.cap / speed * 4)",
             (f"{ENV}::test_reduced_speed_input_caps_the_tool_speed_and_keeps_the_path",)),
    Mutation("watchdog_x10", "watchdog", f"{CHECKS}/watchdog.py",
             "tick.t_ns - last > self._silence_ns", "tick.t_ns - last > 10 * self._silence_ns",
             (f"{ENV}::test_watchdog_stops_a_silent_policy",)),
    Mutation("uncertainty_hold_off", "uncertainty gate (hold)", f"{CHECKS}/uncertainty.py",
             "return self._stop if tick.uncertainty > self._threshold else None", "return None",
             (f"{ENV}::test_uncertainty_gate_holds_when_the_policy_is_unsure",)),
    Mutation("uncertainty_reduce_off", "uncertainty gate (reduced speed)", f"{CHECKS}/uncertainty.py",
             "return self._cap if tick.uncertainty > self._threshold else None", "return None",
             (f"{ENV}::test_uncertainty_gate_reduces_the_tool_speed_when_the_policy_is_unsure",)),
    Mutation("protective_stop_input_off", "safety controller protective-stop input", f"{CHECKS}/safety_input.py",
             "safety = tick.safety", "return None",
             (f"{ENV}::test_protective_stop_input_is_obeyed_through_the_cell",)),
    Mutation("category0_keeps_power", "stop category 0: power removed at once", ENVELOPE,
             "if category == 0 and self.power:", "if False:",
             (f"{ENV}::test_protective_stop_input_is_obeyed_through_the_cell",)),
    Mutation("category1_keeps_power", "stop category 1: power removed at standstill", ENVELOPE,
             "if self.stop_category == 1 and tracker.stopped:", "if False:",
             (STOP,)),
    Mutation("category1_power_off_while_moving", "stop category 1: power removed once the measured joints are still",
             ENVELOPE, "if not speed < STANDSTILL:", "if False:",
             (f"{STOP_POWER}::test_power_stays_on_while_the_measured_arm_still_moves_after_its_setpoint_is_at_rest",)),
    Mutation("category1_never_gives_up", "stop category 1: power removed one stopping time after rest anyway",
             ENVELOPE, "if waited < self._settle_ns:", "if True:",
             (f"{STOP_POWER}::test_power_is_removed_one_stopping_time_after_the_setpoint_rests_on_a_robot_that_never_"
              "reads_still",)),
    Mutation("category1_standstill_from_stale_state", "stop category 1: standstill read only from a fresh state",
             ENVELOPE, "stale, waited = isinstance(state, StaleState), t_ns - self._rest_ns",
             "stale, waited = False, t_ns - self._rest_ns",
             (f"{STALE}::test_a_category_1_stop_waits_for_a_fresh_state_to_read_standstill_from",)),
    Mutation("category1_ended_by_operator_standstill", "stop category 1: power removed before an operator's "
             "standstill ends the cycle", "src/cellguard/runtime/loop.py",
             " and not guard.envelope.removing_power:", ":",
             (f"{STALE}::test_an_operator_signal_during_a_link_category_1_stop_leaves_the_run_with_power_off",)),
    Mutation("stop_never_reaches_zero", "stop categories 1/2: zero velocity within the bound", TRACKER,
             "self._stop_in.target_velocity = np.zeros(dof)", "self._stop_in.target_velocity = np.full(dof, 0.05)",
             (STOP, STOPS)),
    Mutation("stop_slow_deceleration", "stop categories 1/2: time-optimal within the bound", TRACKER,
             "        inp = self._stop_in\n        v, a = self._handover()",
             "        inp = self._stop_in\n        inp.max_acceleration = self.a_max * 0.3\n"
             "        v, a = self._handover()", (STOP, STOPS)),
    Mutation("strictest_stop_not_chosen", "stops: the strictest request wins", ENVELOPE,
             "if request is None or r.category < request.category:", "if request is None:",
             (f"{GUARD}::test_the_strictest_of_two_stops_asked_on_one_tick_wins",)),
    Mutation("stricter_stop_ignored", "stops: a stricter stop overrides the one in force", ENVELOPE,
             "if self.stop_category is not None and self.stop_category <= category:",
             "if self.stop_category is not None:", (f"{GUARD}::test_a_stricter_stop_overrides_the_one_in_force",)),
    Mutation("nan_chunk_accepted", "NaN/inf rejection (chunks)", EXECUTOR,
             "if not np.isfinite(actions).all():", "if False:",
             (f"{EXE}::test_malformed_chunks_become_events",)),
    Mutation("nan_reference_sent", "NaN/inf rejection (reference)", f"{CHECKS}/finite.py",
             "return None if tick.finite else STOP", "return None",
             (f"{PROPS}::test_a_non_finite_reference_is_never_sent",)),
    Mutation("stale_steps_replayed", "stale-step dropping: late steps are not replayed", EXECUTOR,
             "placed = curve.shifted(first) if first != curve.t0_ns else curve",
             "placed = curve.shifted(max(first, now))",
             (f"{EXE}::test_late_steps_are_dropped_not_replayed",)),
    Mutation("plan_from_rest_cut", "stale-step dropping: the first chunk starts when taken, not cut", EXECUTOR,
             "if first <= now and self._chunk is None:", "if False:",
             ("tests/test_executor_from_rest.py::test_a_first_plan_taken_late_starts_at_its_first_step",)),
    Mutation("every_late_chunk_retimed", "stale-step dropping: only the first chunk is re-timed", EXECUTOR,
             "if first <= now and self._chunk is None:", "if first <= now:",
             ("tests/test_executor_from_rest.py::test_after_a_chunk_ran_out_a_late_chunk_drops_its_past_steps",)),
    Mutation("stale_chunk_accepted", "stale-step dropping: a wholly stale chunk is refused", EXECUTOR,
             "if first + (horizon - 1) * curve.h_ns <= now else None", "if False else None",
             (f"{EXE}::test_a_fully_stale_chunk_is_refused",)),
    Mutation("out_of_order_accepted", "stale-step dropping: an older chunk never replaces a newer one", EXECUTOR,
             "chunk.t_obs_ns < self._chunk.t_obs_ns", "chunk.t_obs_ns < -(2**62)",
             (f"{EXE}::test_late_steps_are_dropped_not_replayed",)),
)
