"""A cardiac rehabilitation pathway as a gymnasium environment, with safety costs.

**Not clinically validated.** This is a deliberately simple, plausible simulator built
to exercise safety-focused behaviour cloning on the use case of Boecking & Philipp
(2020): each step is one supervised training session of a cardiac rehabilitation
programme, the action prescribes the session (intensity, duration), the observation is
what the care team measures, and three monitored quantities (heart rate, fatigue,
blood pressure) must stay within limits. The numbers are chosen to be of a realistic
order of magnitude, not fitted to any patient data.

Action (``Box([-1, -1], [1, 1], (2,), float32)``, clipped), see
:func:`action_to_prescription`:

* ``a[0]`` intensity as a fraction of heart-rate reserve (HRR, Karvonen), linearly
  ``-1 -> 30 %`` ... ``+1 -> 90 %`` HRR;
* ``a[1]`` duration of the aerobic part, linearly ``-1 -> 10 min`` ... ``+1 -> 60 min``.

Observation (``Box(0, 3, (12,), float32)``; measured values carry small noise):

====  ==================  ================================================================
idx   name                meaning (scaling)
====  ==================  ================================================================
0     ``hr_rest``         resting heart rate before the next session, bpm / 100
1     ``hr_peak``         peak heart rate of the last session, bpm / 200
2     ``hr_peak_hrr``     that peak as a fraction of HRR, ``(HRpeak-HRrest)/(HRmax-HRrest)``
3     ``sbp_peak``        peak systolic blood pressure of the last session, mmHg / 200
4     ``sbp_rest``        resting systolic blood pressure, mmHg / 200
5     ``fatigue``         fatigue after the last session (0 fresh, 1 = safety limit)
6     ``capacity``        functional capacity, METs / 10
7     ``capacity_rel``    capacity relative to the entry assessment (1.0 at entry)
8     ``progress``        sessions done / programme length, in [0, 1]
9     ``age``             age in years / 100
10    ``last_intensity``  intensity prescribed for the last session, fraction of HRR (0 at entry)
11    ``last_duration``   duration prescribed for the last session, min / 60 (0 at entry)
====  ==================  ================================================================

At reset (entry assessment, no session yet) the "last session" entries hold resting
values: ``hr_peak = hr_rest``, ``hr_peak_hrr = 0``, ``sbp_peak = sbp_rest``.

Safety (``info["safety"]``, ``(3,) float32``, higher is safer) and costs
(``info["cost"]``, ``(3,) float32``, higher is less safe), dims :data:`REHAB_SAFETY_DIMS`.
A cost is the monitored load of the state, the safety its margin to the limit,
``safety = limit - cost`` (see :func:`rehab_costs`, :func:`rehab_safety`):

* ``heart_rate``: cost = peak HR of the last session as a fraction of HRR (Karvonen
  et al. 1957), with HRmax age-predicted by Tanaka et al. (2001), ``208 - 0.7 age``
  (or Fox et al. (1971), ``220 - age``); limit = upper bound of the training zone,
  80 % HRR, the top of the 40-80 % HRR range commonly prescribed in cardiac
  rehabilitation (ACSM's Guidelines for Exercise Testing and Prescription; see also the
  joint EACPR/AACVPR/CACR position statement, Mezzani et al. 2012, and the ESC 2020
  guidelines, Pelliccia et al. 2021, which grade intensity domains in %HRR);
* ``fatigue``: cost = the model's post-session fatigue, limit 1.0 (a model quantity,
  not a clinical scale);
* ``blood_pressure``: cost = peak systolic BP / 100 mmHg; limit 2.2 (220 mmHg), a
  conservative training ceiling below the 250 mmHg at which an exercise test should be
  stopped (Fletcher et al. 2013, AHA exercise standards; ACSM).

``info["offroad"]`` is True when any safety margin is below 0 (a violation: the analogue
of the car leaving the road); ``info["warmup"]`` is always False. Costs are *constraints*:
the reward never uses them or their limits. The ``info`` of ``reset`` and ``step`` both
describe the returned state (at reset: the entry assessment, all margins wide), and also
carry the true values behind it: ``session`` (sessions done), ``intensity_hrr``,
``duration_min``, ``hr_rest_bpm``, ``hr_peak_bpm``, ``sbp_peak_mmhg``, ``fatigue``,
``capacity_mets`` and ``capacity_gain`` (``C/C_0 - 1``).

Reward per session: functional gain in percentage points of the entry capacity,
``100 (C_{t+1} - C_t) / C_0``, minus a well-being penalty
``discomfort_weight * max(0, fatigue - comfort_fatigue)^2`` (an exhausted patient feels
bad and is likely to drop out). Heart rate and blood pressure do not enter the reward.

Dynamics (one session; a fitness-fatigue model in the spirit of Banister et al. 1975):

* training load ``L = (duration / 30 min) * (intensity / 0.5)^2`` (drives fatigue) and
  adaptive stimulus ``S = sqrt(duration / 30 min) * (intensity / 0.5)^2`` (drives gains:
  intensity matters more than duration);
* capacity gain ``C_0 * k_gain * responsiveness * (1 - exp(-S / 2)) * headroom * OT``
  where ``headroom = 1 - (C/C_0 - 1) / (0.5 * responsiveness)`` (diminishing returns
  towards a personal ceiling) and ``OT = 1 - 1.5 clip((F_pre - 0.4) / 0.6, 0, 1)``
  (overtraining: training while fatigued stalls and then reverses gains; a loss is not
  scaled by the headroom);
* fatigue ``F_post = F_pre + 0.15 L / (tolerance * C / C_0)``, and between sessions
  ``F_pre' = retention * F_post`` (recovery);
* peak heart rate ``HRrest + intensity (HRmax - HRrest) hr_reactivity (C_0/C)^0.3
  + 0.15 bpm/min beyond 10 min (cardiovascular drift, Coyle & Gonzalez-Alonso 2001)
  + 6 bpm * F_pre + 2 bpm * e``;
* peak systolic BP ``SBPrest + 80 mmHg * intensity * bp_reactivity + 5 mmHg * F_pre
  + 4 mmHg * e``;
* training lowers resting HR (``-20 bpm * (C/C_0 - 1)``, fatigue adds ``+4 bpm * F_pre``)
  and resting SBP (``-15 mmHg * (C/C_0 - 1)``);
* measurements add noise (HR 1 bpm, SBP 3 mmHg, fatigue 0.03, capacity 0.08 METs, times
  ``RehabConfig.obs_noise``); the safety costs use the true values.

``e`` is a standard normal clipped to +-2.5 (day-to-day variability is bounded, so a
protocol that backs off on warning signs can stay safe while getting close to a limit).

Patients (drawn at every reset with ``self.np_random``, see :func:`sample_patient`)
differ in age, resting HR and BP, entry capacity, responsiveness to training, HR and
BP reactivity, fatigue recovery and tolerance, so the best pathway is personal.

The programme has ``n_sessions`` sessions (default 30: 3 a week for 10 weeks); the env
terminates after the last one (its gymnasium registration,
:func:`safe_bc.tasks.factory.register_envs`, also puts a ``TimeLimit`` of the same length
around it, so the last step reports ``terminated=True`` and ``truncated=True``).

References:
    Karvonen MJ, Kentala E, Mustala O (1957). The effects of training on heart rate; a
    longitudinal study. Ann Med Exp Biol Fenn 35:307-315.
    Fox SM, Naughton JP, Haskell WL (1971). Physical activity and the prevention of
    coronary heart disease. Ann Clin Res 3:404-432.
    Tanaka H, Monahan KD, Seals DR (2001). Age-predicted maximal heart rate revisited.
    J Am Coll Cardiol 37:153-156.
    Banister EW, Calvert TW, Savage MV, Bach T (1975). A systems model of training for
    athletic performance. Aust J Sports Med 7:57-61.
    Coyle EF, Gonzalez-Alonso J (2001). Cardiovascular drift during prolonged exercise.
    Exerc Sport Sci Rev 29:88-92.
    Fletcher GF et al. (2013). Exercise standards for testing and training: a scientific
    statement from the American Heart Association. Circulation 128:873-934.
    American College of Sports Medicine. ACSM's Guidelines for Exercise Testing and
    Prescription (Wolters Kluwer; 10th ed. 2018, 11th ed. 2021).
    Mezzani A et al. (2012). Aerobic exercise intensity assessment and prescription in
    cardiac rehabilitation: a joint position statement of the EACPR, the AACVPR and the
    CACR. J Cardiopulm Rehabil Prev 32:327-350.
    Pelliccia A et al. (2021). 2020 ESC Guidelines on sports cardiology and exercise in
    patients with cardiovascular disease. Eur Heart J 42:17-96.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any, Literal

import gymnasium as gym
import numpy as np
from gymnasium import spaces

DEFAULT_N_SESSIONS = 30
"""Default programme length: 3 sessions a week for 10 weeks."""

REHAB_SAFETY_DIMS: tuple[str, str, str] = ("heart_rate", "fatigue", "blood_pressure")
"""Names of the safety dimensions, in column order of ``info["safety"]`` / ``info["cost"]``."""

OBS_NAMES: tuple[str, ...] = (
    "hr_rest",
    "hr_peak",
    "hr_peak_hrr",
    "sbp_peak",
    "sbp_rest",
    "fatigue",
    "capacity",
    "capacity_rel",
    "progress",
    "age",
    "last_intensity",
    "last_duration",
)
"""Names of the observation entries, in index order (see the module docstring)."""

OBS_INDEX: dict[str, int] = {name: i for i, name in enumerate(OBS_NAMES)}
"""Index of each observation entry by name."""

OBS_HIGH = 3.0
"""Upper bound of every observation entry (values are clipped to ``[0, OBS_HIGH]``)."""

INTENSITY_RANGE: tuple[float, float] = (0.30, 0.90)
"""Intensities (fraction of HRR) that action ``a[0] = -1`` and ``+1`` map to."""

DURATION_RANGE: tuple[float, float] = (10.0, 60.0)
"""Durations (min) that action ``a[1] = -1`` and ``+1`` map to."""

HrMaxFormula = Literal["tanaka", "fox"]


# --------------------------------------------------------------------------- pure functions
def age_predicted_hr_max(age: float | np.ndarray, formula: HrMaxFormula = "tanaka") -> Any:
    """Age-predicted maximal heart rate, bpm.

    ``"tanaka"``: ``208 - 0.7 age`` (Tanaka et al. 2001); ``"fox"``: ``220 - age``
    (Fox et al. 1971). Works on scalars and arrays.

    >>> age_predicted_hr_max(60), age_predicted_hr_max(60, "fox")
    (166.0, 160.0)
    """
    if formula == "tanaka":
        return 208.0 - 0.7 * age
    if formula == "fox":
        return 220.0 - age
    raise ValueError(f"formula must be 'tanaka' or 'fox', got {formula!r}")


def karvonen_target_hr(hr_rest: float, hr_max: float, fraction: float) -> float:
    """Heart rate at ``fraction`` of the heart-rate reserve (Karvonen et al. 1957), bpm.

    ``HRrest + fraction * (HRmax - HRrest)``.

    >>> round(karvonen_target_hr(70.0, 166.0, 0.8), 1)
    146.8
    """
    return hr_rest + fraction * (hr_max - hr_rest)


def hrr_fraction(hr: Any, hr_rest: Any, hr_max: Any) -> Any:
    """Fraction of the heart-rate reserve that heart rate ``hr`` reaches (inverse Karvonen).

    >>> round(hrr_fraction(146.8, 70.0, 166.0), 6)
    0.8
    """
    return (hr - hr_rest) / (hr_max - hr_rest)


@dataclass(frozen=True)
class RehabSafetyLimits:
    """Limits of the three monitored quantities (the constraint thresholds)."""

    hr_zone_upper: float = 0.80
    """Upper bound of the training zone, fraction of HRR (ACSM cardiac rehab: 40-80 %)."""

    fatigue_limit: float = 1.0
    """Highest acceptable post-session fatigue (model units)."""

    sbp_limit_mmhg: float = 220.0
    """Highest acceptable peak systolic BP during training, mmHg."""

    def __post_init__(self) -> None:
        if not 0.0 < self.hr_zone_upper <= 1.0:
            raise ValueError(f"hr_zone_upper must be in (0, 1], got {self.hr_zone_upper}")
        if not self.fatigue_limit > 0.0:
            raise ValueError(f"fatigue_limit must be > 0, got {self.fatigue_limit}")
        if not self.sbp_limit_mmhg > 0.0:
            raise ValueError(f"sbp_limit_mmhg must be > 0, got {self.sbp_limit_mmhg}")

    def as_array(self) -> np.ndarray:
        """``(3,) float32`` limits in cost units, ordered as :data:`REHAB_SAFETY_DIMS`."""
        return np.array(
            [self.hr_zone_upper, self.fatigue_limit, self.sbp_limit_mmhg / 100.0], np.float32
        )


def rehab_costs(hr_peak_hrr: float, fatigue: float, sbp_peak_mmhg: float) -> np.ndarray:
    """Safety costs of a state: the monitored loads (higher is less safe).

    Args:
        hr_peak_hrr: peak heart rate as a fraction of HRR (:func:`hrr_fraction`).
        fatigue: post-session fatigue (model units).
        sbp_peak_mmhg: peak systolic blood pressure, mmHg.

    Returns:
        ``(3,) float32`` ``[hr_peak_hrr, fatigue, sbp_peak / 100]``, ordered as
        :data:`REHAB_SAFETY_DIMS`.

    >>> [round(float(c), 3) for c in rehab_costs(0.75, 0.5, 180.0)]
    [0.75, 0.5, 1.8]
    """
    return np.array([hr_peak_hrr, fatigue, sbp_peak_mmhg / 100.0], np.float32)


def rehab_safety(costs: np.ndarray, limits: RehabSafetyLimits | None = None) -> np.ndarray:
    """Safety margins ``limit - cost`` (higher is safer; negative is a violation).

    Args:
        costs: ``(..., 3)`` costs from :func:`rehab_costs`.
        limits: the thresholds; default :class:`RehabSafetyLimits`.

    Returns:
        ``(..., 3) float32``: HR margin in fractions of HRR, fatigue margin, SBP margin
        in units of 100 mmHg.

    >>> [round(float(m), 3) for m in rehab_safety(rehab_costs(0.75, 0.5, 180.0))]
    [0.05, 0.5, 0.4]
    """
    limits = limits if limits is not None else RehabSafetyLimits()
    return (limits.as_array() - np.asarray(costs, np.float32)).astype(np.float32)


def costs_from_safety(safety: np.ndarray, limits: RehabSafetyLimits | None = None) -> np.ndarray:
    """Inverse of :func:`rehab_safety`: ``limit - safety``, shape as ``safety``.

    >>> [round(float(c), 3) for c in costs_from_safety(np.array([0.05, 0.5, 0.4]))]
    [0.75, 0.5, 1.8]
    """
    limits = limits if limits is not None else RehabSafetyLimits()
    return (limits.as_array() - np.asarray(safety, np.float32)).astype(np.float32)


def is_violation(safety: np.ndarray) -> bool:
    """True when any margin of the ``(3,)`` ``safety`` is below 0."""
    return bool(np.any(np.asarray(safety) < 0.0))


def action_to_prescription(action: np.ndarray) -> tuple[float, float]:
    """Map an action in ``[-1, 1]^2`` (clipped) to ``(intensity_hrr, duration_min)``.

    >>> action_to_prescription(np.array([-1.0, 1.0]))
    (0.3, 60.0)
    >>> [round(v, 3) for v in action_to_prescription(np.zeros(2))]
    [0.6, 35.0]
    """
    a = np.clip(np.asarray(action, np.float64).reshape(2), -1.0, 1.0)
    lo_i, hi_i = INTENSITY_RANGE
    lo_d, hi_d = DURATION_RANGE
    intensity = lo_i + (hi_i - lo_i) * (a[0] + 1.0) / 2.0
    duration = lo_d + (hi_d - lo_d) * (a[1] + 1.0) / 2.0
    return float(intensity), float(duration)


def prescription_to_action(intensity_hrr: float, duration_min: float) -> np.ndarray:
    """Inverse of :func:`action_to_prescription`; ``(2,) float32`` clipped to ``[-1, 1]``.

    >>> prescription_to_action(0.3, 60.0).tolist()
    [-1.0, 1.0]
    """
    lo_i, hi_i = INTENSITY_RANGE
    lo_d, hi_d = DURATION_RANGE
    a0 = 2.0 * (intensity_hrr - lo_i) / (hi_i - lo_i) - 1.0
    a1 = 2.0 * (duration_min - lo_d) / (hi_d - lo_d) - 1.0
    return np.clip(np.array([a0, a1], np.float32), -1.0, 1.0)


def training_load(intensity_hrr: float, duration_min: float) -> float:
    """Dimensionless training load ``(duration / 30) * (intensity / 0.5)^2`` (drives fatigue).

    1.0 is 30 min at 50 % HRR.

    >>> training_load(0.5, 30.0), training_load(0.75, 60.0)
    (1.0, 4.5)
    """
    return (duration_min / 30.0) * (intensity_hrr / 0.5) ** 2


def training_stimulus(intensity_hrr: float, duration_min: float) -> float:
    """Dimensionless adaptive stimulus ``sqrt(duration / 30) * (intensity / 0.5)^2`` (drives
    capacity gains): intensity matters more than duration.

    >>> training_stimulus(0.5, 30.0), training_stimulus(0.75, 120.0)
    (1.0, 4.5)
    """
    return math.sqrt(duration_min / 30.0) * (intensity_hrr / 0.5) ** 2


# --------------------------------------------------------------------------- patients
@dataclass(frozen=True)
class RehabPatient:
    """One simulated patient (fixed for an episode)."""

    age: float
    """Years; ``U(50, 80)``."""

    hr_rest: float
    """Resting heart rate at entry, bpm; ``N(72, 8)`` clipped to [55, 95]."""

    sbp_rest: float
    """Resting systolic BP at entry, mmHg; ``N(132, 12)`` clipped to [105, 170] (higher
    resting values are a contraindication to exercise training)."""

    capacity: float
    """Functional capacity at entry, METs; ``N(6.5 - 0.06 (age - 65), 1.2)`` clipped to
    [3.5, 10]."""

    responsiveness: float
    """Training responsiveness (scales gains and the personal ceiling);
    ``LogNormal(0, 0.35)`` clipped to [0.4, 2.5]."""

    hr_reactivity: float
    """Heart-rate response to a prescribed intensity relative to the age-predicted
    (covers limited cardiac reserve and HRmax prediction error); ``N(1, 0.07)`` clipped to
    [0.85, 1.18]."""

    bp_reactivity: float
    """Systolic BP rise relative to a typical patient; ``N(1, 0.2)`` clipped to [0.6, 1.6]."""

    fatigue_retention: float
    """Share of the post-session fatigue still present at the next session (slow
    recovery is high); ``U(0.3, 0.6)``."""

    fatigue_tolerance: float
    """Divides the fatigue a session causes; ``LogNormal(0, 0.2)`` clipped to [0.6, 1.6]."""

    initial_fatigue: float
    """Fatigue at entry; ``U(0, 0.2)``."""


def sample_patient(rng: np.random.Generator) -> RehabPatient:
    """Draw a patient from the documented distributions (see :class:`RehabPatient`).

    >>> p = sample_patient(np.random.default_rng(0))
    >>> 50 <= p.age <= 80 and 3.5 <= p.capacity <= 10
    True
    """
    age = float(rng.uniform(50.0, 80.0))
    z = rng.standard_normal(7)
    return RehabPatient(
        age=age,
        hr_rest=float(np.clip(72.0 + 8.0 * z[0], 55.0, 95.0)),
        sbp_rest=float(np.clip(132.0 + 12.0 * z[1], 105.0, 170.0)),
        capacity=float(np.clip(6.5 - 0.06 * (age - 65.0) + 1.2 * z[2], 3.5, 10.0)),
        responsiveness=float(np.clip(math.exp(0.35 * z[3]), 0.4, 2.5)),
        hr_reactivity=float(np.clip(1.0 + 0.07 * z[4], 0.85, 1.18)),
        bp_reactivity=float(np.clip(1.0 + 0.2 * z[5], 0.6, 1.6)),
        fatigue_retention=float(rng.uniform(0.3, 0.6)),
        fatigue_tolerance=float(np.clip(math.exp(0.2 * z[6]), 0.6, 1.6)),
        initial_fatigue=float(rng.uniform(0.0, 0.2)),
    )


# --------------------------------------------------------------------------- config
@dataclass(frozen=True)
class RehabConfig:
    """Programme, reward and safety settings of :class:`RehabPathwayEnv`."""

    n_sessions: int = DEFAULT_N_SESSIONS
    """Programme length in sessions (one step each)."""

    hr_max_formula: HrMaxFormula = "tanaka"
    """Age-predicted HRmax that turns %HRR (prescriptions, zone bound) into bpm: Tanaka
    (2001) or Fox (1971)."""

    limits: RehabSafetyLimits = RehabSafetyLimits()
    """Safety limits (constraints; never part of the reward)."""

    gain_rate: float = 0.012
    """``k_gain``: capacity gain per session, fraction of entry capacity, at saturating
    stimulus, unit responsiveness and full headroom."""

    comfort_fatigue: float = 0.7
    """Fatigue above which the patient feels discomfort (reward penalty)."""

    discomfort_weight: float = 5.0
    """Weight of the squared fatigue excess in the reward."""

    obs_noise: float = 1.0
    """Scale of the measurement noise on observations (0 disables it)."""

    def __post_init__(self) -> None:
        if self.n_sessions < 1:
            raise ValueError(f"n_sessions must be >= 1, got {self.n_sessions}")
        if self.hr_max_formula not in ("tanaka", "fox"):
            raise ValueError(f"hr_max_formula must be 'tanaka' or 'fox', got {self.hr_max_formula}")
        for name in ("gain_rate", "discomfort_weight", "obs_noise", "comfort_fatigue"):
            if not getattr(self, name) >= 0.0:
                raise ValueError(f"RehabConfig.{name} must be >= 0, got {getattr(self, name)}")


# --------------------------------------------------------------------------- environment
_FATIGUE_GAIN = 0.15
_STIM_SAT = 2.0
_CEILING_PER_RESP = 0.5
_OT_ONSET, _OT_SPAN, _OT_DEPTH = 0.4, 0.6, 1.5
_HR_DRIFT_BPM_PER_MIN, _HR_FATIGUE_BPM, _HR_NOISE_BPM = 0.15, 6.0, 2.0
_SBP_RISE_MMHG, _SBP_FATIGUE_MMHG, _SBP_NOISE_MMHG = 80.0, 5.0, 4.0
_HR_REST_TRAINING, _HR_REST_FATIGUE, _SBP_REST_TRAINING = 20.0, 4.0, 15.0
_OBS_NOISE_SD = {"hr": 1.0, "sbp": 3.0, "fatigue": 0.03, "capacity": 0.08}
_NOISE_CLIP = 2.5


class RehabPathwayEnv(gym.Env):
    """Cardiac rehabilitation programme: one step per training session.

    See the module docstring for the observation, action, safety, reward and dynamics.
    ``reset(options={"patient": RehabPatient(...)})`` replays a given patient instead of
    drawing one.

    >>> env = RehabPathwayEnv()
    >>> obs, info = env.reset(seed=0)
    >>> obs.shape, obs.dtype, info["safety"].shape, info["offroad"]
    ((12,), dtype('float32'), (3,), False)
    >>> action = prescription_to_action(0.5, 30.0)  # 50 % HRR for 30 min
    >>> obs, reward, terminated, truncated, info = env.step(action)
    >>> round(float(obs[OBS_INDEX["progress"]]), 3), terminated
    (0.033, False)
    >>> round(info["intensity_hrr"], 2), round(info["duration_min"], 1)
    (0.5, 30.0)
    >>> bool(info["cost"][0] < RehabSafetyLimits().hr_zone_upper)  # below 80 % HRR
    True
    """

    metadata: dict[str, Any] = {"render_modes": []}  # noqa: RUF012

    def __init__(self, config: RehabConfig | None = None, render_mode: str | None = None) -> None:
        if render_mode is not None:
            raise ValueError("RehabPathwayEnv does not render")
        self.config = config if config is not None else RehabConfig()
        self.render_mode = render_mode
        self.safety_dims = REHAB_SAFETY_DIMS
        self.action_space = spaces.Box(-1.0, 1.0, shape=(2,), dtype=np.float32)
        self.observation_space = spaces.Box(
            0.0, OBS_HIGH, shape=(len(OBS_NAMES),), dtype=np.float32
        )
        self.patient: RehabPatient | None = None
        self._t = 0
        self._capacity = 0.0
        self._fatigue_pre = 0.0
        self._last: dict[str, float] = {}

    # ------------------------------------------------------------------ helpers
    @property
    def hr_max(self) -> float:
        """Age-predicted HRmax of the current patient, bpm."""
        assert self.patient is not None, "call reset() first"
        return float(age_predicted_hr_max(self.patient.age, self.config.hr_max_formula))

    @property
    def capacity_rel(self) -> float:
        """Current capacity over entry capacity."""
        assert self.patient is not None, "call reset() first"
        return self._capacity / self.patient.capacity

    def _clipped_normal(self, n: int) -> np.ndarray:
        """``(n,)`` standard normal draws clipped to +-``_NOISE_CLIP`` (bounded variability)."""
        return np.clip(self.np_random.standard_normal(n), -_NOISE_CLIP, _NOISE_CLIP)

    def _hr_rest_now(self) -> float:
        p = self.patient
        gain = self.capacity_rel - 1.0
        return p.hr_rest - _HR_REST_TRAINING * gain + _HR_REST_FATIGUE * self._fatigue_pre

    def _sbp_rest_now(self) -> float:
        return self.patient.sbp_rest - _SBP_REST_TRAINING * (self.capacity_rel - 1.0)

    def _costs(self) -> np.ndarray:
        last = self._last
        return rehab_costs(last["hr_peak_hrr"], last["fatigue"], last["sbp_peak"])

    def _info(self) -> dict[str, Any]:
        costs = self._costs()
        safety = rehab_safety(costs, self.config.limits)
        return {
            "safety": safety,
            "cost": costs,
            "offroad": is_violation(safety),
            "warmup": False,
            "session": self._t,
            "intensity_hrr": self._last["intensity"],
            "duration_min": self._last["duration"],
            "hr_rest_bpm": self._last["hr_rest"],
            "hr_peak_bpm": self._last["hr_peak"],
            "sbp_peak_mmhg": self._last["sbp_peak"],
            "fatigue": self._last["fatigue"],
            "capacity_mets": self._capacity,
            "capacity_gain": self.capacity_rel - 1.0,
        }

    def _obs(self) -> np.ndarray:
        noise = self.config.obs_noise * self._clipped_normal(6)
        sd = _OBS_NOISE_SD
        hr_rest = self._hr_rest_now() + sd["hr"] * noise[0]
        hr_peak = self._last["hr_peak"] + sd["hr"] * noise[1]
        if self._t == 0:
            hr_peak = hr_rest
        hr_hrr = max(0.0, hrr_fraction(hr_peak, hr_rest, self.hr_max))
        sbp_rest = self._sbp_rest_now() + sd["sbp"] * noise[2]
        sbp_peak = sbp_rest if self._t == 0 else self._last["sbp_peak"] + sd["sbp"] * noise[3]
        capacity = self._capacity + sd["capacity"] * noise[5]
        obs = np.array(
            [
                hr_rest / 100.0,
                hr_peak / 200.0,
                hr_hrr,
                sbp_peak / 200.0,
                sbp_rest / 200.0,
                self._last["fatigue"] + sd["fatigue"] * noise[4],
                capacity / 10.0,
                capacity / self.patient.capacity,
                self._t / self.config.n_sessions,
                self.patient.age / 100.0,
                self._last["intensity"],
                self._last["duration"] / 60.0,
            ],
            dtype=np.float64,
        )
        return np.clip(obs, 0.0, OBS_HIGH).astype(np.float32)

    # ------------------------------------------------------------------ gym API
    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        """Draw (or take from ``options["patient"]``) a patient; return the entry state."""
        super().reset(seed=seed)
        patient = (options or {}).get("patient")
        if patient is None:
            patient = sample_patient(self.np_random)
        elif not isinstance(patient, RehabPatient):
            raise TypeError(f"options['patient'] must be a RehabPatient, got {type(patient)}")
        self.patient = patient
        self._t = 0
        self._capacity = patient.capacity
        self._fatigue_pre = patient.initial_fatigue
        hr_rest = self._hr_rest_now()
        self._last = {
            "hr_rest": hr_rest,
            "hr_peak": hr_rest,
            "hr_peak_hrr": 0.0,
            "sbp_peak": self._sbp_rest_now(),
            "fatigue": patient.initial_fatigue,
            "intensity": 0.0,
            "duration": 0.0,
        }
        return self._obs(), self._info()

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        """Run one session with the prescription ``action`` (``(2,)``, see the module)."""
        if self.patient is None:
            raise RuntimeError("call reset() before step()")
        if self._t >= self.config.n_sessions:
            raise RuntimeError("the programme is over; call reset()")
        p, cfg = self.patient, self.config
        if not np.all(np.isfinite(np.asarray(action, np.float64))):
            raise ValueError(f"action must be finite, got {action!r}")
        intensity, duration = action_to_prescription(action)
        rel = self.capacity_rel
        f_pre = self._fatigue_pre
        hr_rest = self._hr_rest_now()
        hr_max = self.hr_max
        z = self._clipped_normal(2)

        # Session response (true physiology; the safety costs come from these).
        hr_peak = (
            hr_rest
            + intensity * (hr_max - hr_rest) * p.hr_reactivity * rel**-0.3
            + _HR_DRIFT_BPM_PER_MIN * max(0.0, duration - 10.0)
            + _HR_FATIGUE_BPM * f_pre
            + _HR_NOISE_BPM * z[0]
        )
        hr_peak = max(hr_peak, hr_rest)
        sbp_peak = (
            self._sbp_rest_now()
            + _SBP_RISE_MMHG * intensity * p.bp_reactivity
            + _SBP_FATIGUE_MMHG * f_pre
            + _SBP_NOISE_MMHG * z[1]
        )
        load = training_load(intensity, duration)
        stim = training_stimulus(intensity, duration)
        f_post = f_pre + _FATIGUE_GAIN * load / (p.fatigue_tolerance * rel)

        # Adaptation.
        ceiling = _CEILING_PER_RESP * p.responsiveness
        headroom = max(0.0, 1.0 - (rel - 1.0) / ceiling)
        overtraining = 1.0 - _OT_DEPTH * min(max((f_pre - _OT_ONSET) / _OT_SPAN, 0.0), 1.0)
        gain = (
            cfg.gain_rate
            * p.responsiveness
            * (1.0 - math.exp(-stim / _STIM_SAT))
            * (headroom if overtraining > 0 else 1.0)
            * overtraining
        )
        new_capacity = max(0.5 * p.capacity, self._capacity + p.capacity * gain)
        reward = 100.0 * (new_capacity - self._capacity) / p.capacity
        reward -= cfg.discomfort_weight * max(0.0, f_post - cfg.comfort_fatigue) ** 2

        self._capacity = new_capacity
        self._fatigue_pre = p.fatigue_retention * f_post
        self._t += 1
        self._last = {
            "hr_rest": hr_rest,
            "hr_peak": hr_peak,
            "hr_peak_hrr": hrr_fraction(hr_peak, hr_rest, hr_max),
            "sbp_peak": sbp_peak,
            "fatigue": f_post,
            "intensity": intensity,
            "duration": duration,
        }
        terminated = self._t >= cfg.n_sessions
        return self._obs(), float(reward), terminated, False, self._info()

    def patient_dict(self) -> dict[str, float]:
        """The current patient as a plain dict (for logs)."""
        assert self.patient is not None, "call reset() first"
        return asdict(self.patient)


__all__ = [
    "DEFAULT_N_SESSIONS",
    "OBS_INDEX",
    "OBS_NAMES",
    "REHAB_SAFETY_DIMS",
    "RehabConfig",
    "RehabPathwayEnv",
    "RehabPatient",
    "RehabSafetyLimits",
    "action_to_prescription",
    "age_predicted_hr_max",
    "costs_from_safety",
    "hrr_fraction",
    "is_violation",
    "karvonen_target_hr",
    "prescription_to_action",
    "rehab_costs",
    "rehab_safety",
    "sample_patient",
    "training_stimulus",
]


def observed_costs(obs: np.ndarray) -> np.ndarray:
    """Measured safety costs of observations ``(B, obs_dim) -> (B, 3) float64``:
    ``[hr_peak_hrr, fatigue, 2 * sbp_peak]``, the noisy readings of the env's true costs."""
    o = np.asarray(obs).astype(np.float64)
    cols = [o[:, OBS_INDEX["hr_peak_hrr"]], o[:, OBS_INDEX["fatigue"]]]
    return np.stack([*cols, 2.0 * o[:, OBS_INDEX["sbp_peak"]]], axis=1)
