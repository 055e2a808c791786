"""The handover's settings: per-dimension widths and the capping fallback, their identity, and
the deferring policy that carries them out on the real rehab env."""

from __future__ import annotations

import numpy as np
import pytest

from safe_bc.handover import HandoverConfig
from safe_bc.rollout.collect import build_expert
from safe_bc.rollout.handover import cap_action, handover_source
from safe_bc.tasks import make_env, task_defaults


def test_a_handover_without_the_new_fields_keeps_its_identity() -> None:
    assert HandoverConfig(2.0, lookahead=6, hold=6, hold_on=("front",)).to_dict() == {
        "width": 2.0, "lookahead": 6, "hold": 6, "hold_on": ["front"],
    }  # fmt: skip


def test_widths_and_fallback_round_trip_and_are_checked() -> None:
    h = HandoverConfig(0.2, widths=(("fatigue", 0.15), ("heart_rate", 0.1)), fallback="cap")
    assert HandoverConfig.from_dict(h.to_dict()) == h
    assert h.width_per_dim(("heart_rate", "fatigue", "blood_pressure")) == (0.1, 0.15, 0.2)
    assert "capping" in h.label()
    with pytest.raises(ValueError, match="unknown dimension"):
        h.width_per_dim(("left", "front"))
    with pytest.raises(ValueError, match="fallback"):
        HandoverConfig(0.2, fallback="agent")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="fatigue"):
        HandoverConfig(0.2, widths=(("fatigue", -1.0),))


def test_cap_keeps_each_component_on_the_safer_side() -> None:
    own, expert = np.array([0.5, -0.5, 0.1]), np.array([0.2, 0.0, 0.3])
    assert cap_action(own, expert, np.array([-1, -1, 1])).tolist() == pytest.approx(
        [0.2, -0.5, 0.3]
    )


class _Fixed:
    """A policy that always prescribes the same session."""

    def __init__(self, action: tuple[float, float]) -> None:
        self.action = np.asarray(action, np.float32)

    def reset(self, env, rng) -> None:
        pass

    def act(self, obs, env):
        return self.action


class _Source:
    def __init__(self, action: tuple[float, float]) -> None:
        self.action = action

    def build(self) -> _Fixed:
        return _Fixed(self.action)


def _run(handover: HandoverConfig, action: tuple[float, float], steps: int = 12) -> tuple:
    rehab = task_defaults("rehab")
    limits = np.array([0.75, 5.0, 5.0])  # heart rate alone can reach its zone
    policy = handover_source(
        _Source(action), handover, rehab.expert, limits, rehab.safety_dims
    ).build()
    env = make_env(rehab.env)
    obs, info = env.reset(seed=3)
    policy.reset(env, np.random.default_rng(3))
    expert = build_expert(rehab.expert)
    expert.reset(env, np.random.default_rng(3))
    acted = []
    for _ in range(steps):
        policy.see(info)
        acted.append(np.asarray(policy.act(obs, env)))
        obs, _, term, trunc, info = env.step(acted[-1])
        if term or trunc:
            break
    env.close()
    return np.array(acted), np.array(policy.flags)


def test_per_dimension_widths_decide_the_zone() -> None:
    """A heart-rate width of 0 never defers below d_s; a wide one defers once the rate is up."""
    narrow = HandoverConfig(0.0, widths=(("heart_rate", 0.0),))
    wide = HandoverConfig(0.0, widths=(("heart_rate", 0.25),))
    _, flags_narrow = _run(narrow, (0.0, 0.0))
    _, flags_wide = _run(wide, (0.0, 0.0))
    assert flags_wide.sum() > flags_narrow.sum()


def test_the_cap_never_prescribes_more_than_the_agent_or_the_expert() -> None:
    wide = {"widths": (("heart_rate", 0.25),)}
    hard, _ = _run(HandoverConfig(0.0, **wide), (1.0, 1.0))
    capped, flags = _run(HandoverConfig(0.0, fallback="cap", **wide), (1.0, 1.0))
    assert flags.any() and (~flags).any()
    assert (capped <= 1.0).all()
    assert (capped[flags] < 1.0).any()  # where the guideline prescribes less, it caps
    assert (capped[~flags] == 1.0).all()  # outside the zone the agent acts
    assert hard.shape[1] == capped.shape[1] == 2


@pytest.mark.parametrize("fallback", ["cap", "safest"])
def test_a_handover_needing_a_safer_direction_is_refused_where_the_task_has_none(
    fallback,
) -> None:
    car = task_defaults("carracing")
    with pytest.raises(ValueError, match=f"'{fallback}' handover needs a safer direction: 'car"):
        handover_source(_Source((0.0, 0.0, 0.0)), HandoverConfig(2.0, fallback=fallback),
                        car.expert, np.ones(3), car.safety_dims)  # fmt: skip


def test_the_safest_handover_prescribes_the_lightest_session_in_the_zone_only() -> None:
    wide = {"widths": (("heart_rate", 0.25),)}
    safest, flags = _run(HandoverConfig(0.0, fallback="safest", **wide), (1.0, 1.0))
    assert flags.any() and (~flags).any()
    assert (safest[flags] == -1.0).all()  # 30% HRR for 10 min: both bounds of the box
    assert (safest[~flags] == 1.0).all()  # outside the zone the agent acts
    assert HandoverConfig(0.1, fallback="safest").label() == "the safest action within 0.1 of d_s"


def test_policy_args_carry_the_widths_and_the_safer_direction() -> None:
    rehab = task_defaults("rehab")
    h = HandoverConfig(0.2, widths=(("heart_rate", 0.1),), fallback="cap")
    zone, hold, lookahead, hold_on, safer, safest, stall, pace = handover_source(
        None, h, rehab.expert, (0.8, 0.8, 2.0), rehab.safety_dims
    ).policy_args()
    flags = zone.per_dim(np.array([[0.71, 0.61, 1.79], [0.69, 0.59, 1.81]]))
    assert flags.tolist() == [[True, True, False], [False, False, True]]
    assert (hold, lookahead, hold_on, safer, safest, stall) == (0, 0, None, (-1, -1), False, (0, 0))
    assert pace == (0.0, 0, 0)


def test_a_handover_read_back_from_sorted_json_equals_the_one_written() -> None:
    import json

    h = HandoverConfig(0.2, widths=(("heart_rate", 0.1), ("fatigue", 0.1)), fallback="safest")
    back = HandoverConfig.from_dict(json.loads(json.dumps(h.to_dict(), sort_keys=True)))
    assert back.widths != h.widths and back == h and hash(back) == hash(h)
    assert back != HandoverConfig(0.2, widths=(("heart_rate", 0.1),), fallback="safest")


def test_a_stall_restart_enters_the_identity_only_where_set() -> None:
    plain = HandoverConfig(2.0, lookahead=6, hold=6, hold_on=("front",))
    assert "stall" not in plain.to_dict()  # every committed handover keeps its identity
    restart = HandoverConfig(2.0, lookahead=6, hold=6, hold_on=("front",), stall=20, stall_hold=50)
    assert restart.to_dict()["stall"] == 20 and restart.to_dict()["stall_hold"] == 50
    assert HandoverConfig.from_dict(restart.to_dict()) == restart != plain
    assert "50 steps after 20 still steps" in restart.label(" px")
    with pytest.raises(ValueError, match="stall"):
        HandoverConfig(2.0, stall=-1)


def test_the_expert_restarts_an_agent_whose_costs_stand_still() -> None:
    """An agent that stops outside the zone: after ``stall`` steps of an unchanged cost the
    expert acts for ``stall_hold`` steps; never in warm-up; off without ``stall``."""
    from safe_bc.rollout.handover import DeferringPolicy
    from safe_bc.selection import CriticalZone

    class Const:
        def __init__(self, a: float) -> None:
            self.a = np.array([a], np.float32)

        def reset(self, env=None, rng=None) -> None:
            pass

        def act(self, obs, env=None):
            return self.a

    def run(stall: tuple[int, int], warmup: bool) -> list[float]:
        policy = DeferringPolicy(
            Const(0.0), Const(1.0), CriticalZone((10.0,), 1.0, "any"), stall=stall
        )
        policy.reset(None, None)
        out = []
        for t in range(8):
            cost = [2.0] if t < 6 else [2.0 + 0.1 * t]  # still for 6 steps, then moving
            policy.see({"cost": cost, "warmup": warmup})
            out.append(float(policy.act(np.zeros(1), None)[0]))
        return out

    assert run((3, 2), False) == [0, 0, 0, 1, 1, 0, 0, 0]
    assert run((3, 2), True) == [0] * 8
    assert run((0, 0), False) == [0] * 8


def test_a_pace_rule_enters_the_identity_only_where_set() -> None:
    import json

    plain = HandoverConfig(2.0, lookahead=6, hold=6, hold_on=("front",), stall=20, stall_hold=100)
    assert "pace" not in plain.to_dict()  # the second design's rows keep their identity
    paced = HandoverConfig(
        2.0, lookahead=6, hold=6, hold_on=("front",), stall=20, stall_hold=100,
        pace=30.0, pace_steps=10, pace_hold=50,
    )  # fmt: skip
    d = paced.to_dict()
    assert (d["pace"], d["pace_steps"], d["pace_hold"]) == (30.0, 10, 50)
    back = HandoverConfig.from_dict(json.loads(json.dumps(d, sort_keys=True)))
    assert back == paced != plain and hash(back) == hash(paced)
    assert "50 steps after 10 steps below speed 30" in paced.label(" px")
    source = handover_source(None, paced, task_defaults("carracing").expert, (40, 50, 40),
                             task_defaults("carracing").safety_dims)  # fmt: skip
    assert source.policy_args()[-1] == (30.0, 10, 50)
    for bad in ({"pace": -1.0, "pace_steps": 1, "pace_hold": 1}, {"pace": 30.0},
                {"pace": float("nan"), "pace_steps": 1, "pace_hold": 1}):  # fmt: skip
        with pytest.raises(ValueError, match="pace"):
            HandoverConfig(2.0, **bad)


def test_the_expert_drives_a_car_that_falls_below_pace() -> None:
    """A car crawling outside the zone: after ``pace_steps`` steps below ``pace`` the expert
    acts for ``pace_hold`` steps; never in warm-up; off without ``pace``; the speed is the
    car's hull velocity."""
    from types import SimpleNamespace

    from safe_bc.rollout.handover import DeferringPolicy
    from safe_bc.selection import CriticalZone

    class Const:
        def __init__(self, a: float) -> None:
            self.a = np.array([a], np.float32)

        def reset(self, env=None, rng=None) -> None:
            pass

        def act(self, obs, env=None):
            return self.a

    hull = SimpleNamespace(linearVelocity=(0.0, 0.0))
    env = SimpleNamespace(unwrapped=SimpleNamespace(car=SimpleNamespace(hull=hull)))

    def run(pace: tuple[float, int, int], warmup: bool) -> list[float]:
        policy = DeferringPolicy(
            Const(0.0), Const(1.0), CriticalZone((10.0,), 1.0, "any"), pace=pace
        )
        policy.reset(None, None)
        out = []
        for t, v in enumerate((50, 40, 20, 18, 15, 30, 60, 60, 60)):
            hull.linearVelocity = (0.6 * v, 0.8 * v)
            policy.see({"cost": [2.0 + 0.1 * t], "warmup": warmup})
            out.append(float(policy.act(np.zeros(1), env)[0]))
        return out

    assert run((25.0, 3, 2), False) == [0, 0, 0, 0, 1, 1, 0, 0, 0]
    assert run((25.0, 3, 2), True) == [0] * 9
    assert run((0.0, 0, 0), False) == [0] * 9
