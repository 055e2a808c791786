"""Rule-based "blueprint" clinician for :class:`safe_bc.tasks.rehab.env.RehabPathwayEnv`.

The guideline protocol starts low (about 40 % of heart-rate reserve for 15 min; 30 % for
patients entering with a high resting blood pressure),
progresses intensity and duration slowly within the guideline zone (capped at 65 % HRR
and 45 min), and backs off on warning signs read from the observation: a peak heart rate
close to the zone's upper bound (80 % HRR), high post-session fatigue, or a high peak
systolic blood pressure. It is safe but sub-optimal: it treats every patient alike, so
responsive patients who could progress faster are held back.

The expert is *not* privileged: it reads only the observation (the measurements a care
team has), including the last prescription (``obs[10:12]``), so its decision is a
function of the observation and of the per-episode clinician variation drawn in
:meth:`GuidelineExpert.reset`. Because it progresses from the *executed* last
prescription, it also recovers sensibly from perturbed actions.

The shape of the protocol (start at a low-moderate intensity, lengthen the sessions
and raise the intensity gradually as tolerated, stay inside the prescribed HRR zone)
follows the usual cardiac-rehabilitation advice, e.g. Squires RW et al. (2018),
Progression of exercise training in early outpatient cardiac rehabilitation: an official
statement from the AACVPR, J Cardiopulm Rehabil Prev 38:139-146. The numbers are this
simulator's, not a clinical recommendation.

Also here: :class:`ConstantPrescription` (the same session every time; e.g. naive
aggression) for baselines and tests.
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace

import gymnasium as gym
import numpy as np

from safe_bc.tasks.rehab.env import (
    DURATION_RANGE,
    INTENSITY_RANGE,
    OBS_INDEX,
    prescription_to_action,
)


@dataclass(frozen=True)
class GuidelineConfig:
    """One clinician's version of the blueprint protocol; defaults are conservative.

    Intensities are fractions of heart-rate reserve (HRR), durations minutes, blood
    pressures mmHg, fatigue in the environment's units (1.0 = safety limit).
    """

    start_intensity: float = 0.40
    """Intensity of the first session."""

    start_duration_min: float = 15.0
    """Duration of the first session."""

    cautious_start_sbp_mmhg: float = 150.0
    """Resting systolic BP at entry at or above which the first session starts at the
    lowest intensity (30 % HRR) instead of ``start_intensity``."""

    intensity_step: float = 0.01
    """Intensity added after a session without warning signs."""

    duration_step_min: float = 1.0
    """Minutes added after a session without fatigue warning."""

    max_intensity: float = 0.65
    """Highest intensity the protocol prescribes (guideline zone cap)."""

    max_duration_min: float = 45.0
    """Longest session the protocol prescribes."""

    hr_hold: float = 0.68
    """Observed peak HR (fraction of HRR) at or above which intensity is held."""

    hr_backoff: float = 0.72
    """Observed peak HR (fraction of HRR) at or above which intensity is reduced."""

    fatigue_hold: float = 0.70
    """Observed fatigue at or above which intensity and duration are held."""

    fatigue_backoff: float = 0.80
    """Observed fatigue at or above which duration (and intensity) are reduced."""

    sbp_hold_mmhg: float = 200.0
    """Observed peak systolic BP at or above which intensity is held."""

    sbp_backoff_mmhg: float = 208.0
    """Observed peak systolic BP at or above which intensity is reduced."""

    intensity_backoff: float = 0.05
    """Intensity removed on an HR or BP warning (half of it on a fatigue warning)."""

    duration_backoff_min: float = 5.0
    """Minutes removed on a fatigue warning."""

    clinician_jitter: float = 0.3
    """Per-episode variation between clinicians, drawn in ``reset`` from the rng: with
    ``u ~ U(-1, 1)`` per field, the start values and steps are scaled by ``1 + j u``, the
    caps by ``1 + j u / 3`` and the warning thresholds by ``1 + j u / 6`` (so ``0.3``
    moves ``hr_backoff`` within 0.70 +- 0.035). 0 gives the same protocol every episode."""

    def __post_init__(self) -> None:
        lo_i, hi_i = INTENSITY_RANGE
        lo_d, hi_d = DURATION_RANGE
        for name in ("start_intensity", "max_intensity"):
            v = getattr(self, name)
            if not lo_i <= v <= hi_i:
                raise ValueError(f"GuidelineConfig.{name} must be in [{lo_i}, {hi_i}], got {v}")
        for name in ("start_duration_min", "max_duration_min"):
            v = getattr(self, name)
            if not lo_d <= v <= hi_d:
                raise ValueError(f"GuidelineConfig.{name} must be in [{lo_d}, {hi_d}], got {v}")
        for name in (
            "intensity_step",
            "duration_step_min",
            "intensity_backoff",
            "duration_backoff_min",
        ):
            if not getattr(self, name) >= 0:
                raise ValueError(f"GuidelineConfig.{name} must be >= 0, got {getattr(self, name)}")
        if not 0.0 <= self.clinician_jitter < 1.0:
            raise ValueError(f"clinician_jitter must be in [0, 1), got {self.clinician_jitter}")
        for hold, back in (
            ("hr_hold", "hr_backoff"),
            ("fatigue_hold", "fatigue_backoff"),
            ("sbp_hold_mmhg", "sbp_backoff_mmhg"),
        ):
            if getattr(self, hold) > getattr(self, back):
                raise ValueError(f"GuidelineConfig.{hold} must be <= {back}")

    @classmethod
    def accelerated(cls) -> GuidelineConfig:
        """A faster, less cautious progression (*not* a clinical protocol).

        Starts at 50 % HRR for 30 min, adds 2 % HRR and 3 min per good session up to
        72 % HRR and 60 min, and holds or backs off only closer to the limits. Used to show that the
        blueprint leaves reward on the table.
        """
        return cls(
            start_intensity=0.50,
            start_duration_min=30.0,
            intensity_step=0.02,
            duration_step_min=3.0,
            max_intensity=0.72,
            max_duration_min=60.0,
            hr_hold=0.68,
            hr_backoff=0.72,
            fatigue_hold=0.75,
            fatigue_backoff=0.85,
            sbp_hold_mmhg=198.0,
            sbp_backoff_mmhg=205.0,
            clinician_jitter=0.0,
        )

    def jittered(self, rng: np.random.Generator) -> GuidelineConfig:
        """This protocol as varied by one clinician (see ``clinician_jitter``)."""
        j = self.clinician_jitter
        if j == 0.0:
            return self
        scale = {
            "start_intensity": j,
            "start_duration_min": j,
            "intensity_step": j,
            "duration_step_min": j,
            "max_intensity": j / 3,
            "max_duration_min": j / 3,
            "hr_hold": j / 10,
            "hr_backoff": j / 10,
            "fatigue_hold": j / 10,
            "fatigue_backoff": j / 10,
            "cautious_start_sbp_mmhg": j / 10,
            "sbp_hold_mmhg": j / 10,
            "sbp_backoff_mmhg": j / 10,
        }
        u = rng.uniform(-1.0, 1.0, size=len(scale))
        values = {
            k: getattr(self, k) * (1.0 + s * ui)
            for (k, s), ui in zip(scale.items(), u, strict=True)
        }
        lo_i, hi_i = INTENSITY_RANGE
        lo_d, hi_d = DURATION_RANGE
        for k in ("start_intensity", "max_intensity"):
            values[k] = float(np.clip(values[k], lo_i, hi_i))
        for k in ("start_duration_min", "max_duration_min"):
            values[k] = float(np.clip(values[k], lo_d, hi_d))
        for hold, back in (
            ("hr_hold", "hr_backoff"),
            ("fatigue_hold", "fatigue_backoff"),
            ("sbp_hold_mmhg", "sbp_backoff_mmhg"),
        ):
            values[hold] = min(values[hold], values[back])
        return replace(self, **{k: float(v) for k, v in values.items()})

    def as_dict(self) -> dict[str, float]:
        """The fields as a plain dict (for logs and metadata)."""
        return {f.name: getattr(self, f.name) for f in fields(self)}


class GuidelineExpert:
    """The blueprint clinician, implementing :class:`~safe_bc.policy.Policy`.

    >>> from safe_bc.tasks.rehab.env import RehabPathwayEnv
    >>> env = RehabPathwayEnv()
    >>> obs, info = env.reset(seed=0)
    >>> expert = GuidelineExpert()
    >>> expert.reset(env, np.random.default_rng(0))
    >>> action = expert.act(obs, env)
    >>> action.shape, action.dtype
    ((2,), dtype('float32'))
    """

    def __init__(self, config: GuidelineConfig | None = None) -> None:
        self.config = config if config is not None else GuidelineConfig()
        self.episode_config = self.config

    def reset(self, env: gym.Env | None, rng: np.random.Generator) -> None:
        """Draw this episode's clinician variation from ``rng``; call after ``env.reset``."""
        self.episode_config = self.config.jittered(rng)

    def prescribe(self, obs: np.ndarray) -> tuple[float, float]:
        """Next session ``(intensity_hrr, duration_min)`` for the ``(12,)`` observation."""
        c = self.episode_config
        last_i = float(obs[OBS_INDEX["last_intensity"]])
        last_d = float(obs[OBS_INDEX["last_duration"]]) * 60.0
        if last_d <= 0.0:  # entry assessment: no session yet
            if float(obs[OBS_INDEX["sbp_rest"]]) * 200.0 >= c.cautious_start_sbp_mmhg:
                return INTENSITY_RANGE[0], c.start_duration_min
            return c.start_intensity, c.start_duration_min
        hr = float(obs[OBS_INDEX["hr_peak_hrr"]])
        fatigue = float(obs[OBS_INDEX["fatigue"]])
        sbp = float(obs[OBS_INDEX["sbp_peak"]]) * 200.0

        intensity, duration = last_i, last_d
        if hr >= c.hr_backoff or sbp >= c.sbp_backoff_mmhg:
            intensity -= c.intensity_backoff
        elif fatigue >= c.fatigue_backoff:
            intensity -= c.intensity_backoff / 2
        elif not (hr >= c.hr_hold or sbp >= c.sbp_hold_mmhg or fatigue >= c.fatigue_hold):
            intensity += c.intensity_step
        if fatigue >= c.fatigue_backoff:
            duration -= c.duration_backoff_min
        elif fatigue < c.fatigue_hold:
            duration += c.duration_step_min
        lo_i, _ = INTENSITY_RANGE
        lo_d, _ = DURATION_RANGE
        intensity = min(max(intensity, lo_i), max(c.max_intensity, lo_i))
        duration = min(max(duration, lo_d), max(c.max_duration_min, lo_d))
        return intensity, duration

    def act(self, obs: np.ndarray, env: gym.Env | None = None) -> np.ndarray:
        """Action ``(2,) float32`` in ``[-1, 1]`` encoding :meth:`prescribe`."""
        return prescription_to_action(*self.prescribe(np.asarray(obs)))


@dataclass(frozen=True)
class ConstantPrescription:
    """The same session every time, implementing :class:`~safe_bc.policy.Policy`.

    ``ConstantPrescription(0.9, 60.0)`` is naive aggression (above the 80 % HRR zone).
    """

    intensity_hrr: float
    """Intensity, fraction of HRR, in ``INTENSITY_RANGE``."""

    duration_min: float
    """Duration, minutes, in ``DURATION_RANGE``."""

    def reset(self, env: gym.Env | None, rng: np.random.Generator) -> None:
        """Nothing to reset."""

    def act(self, obs: np.ndarray, env: gym.Env | None = None) -> np.ndarray:
        """Action ``(2,) float32`` encoding the fixed prescription."""
        return prescription_to_action(self.intensity_hrr, self.duration_min)


__all__ = ["ConstantPrescription", "GuidelineConfig", "GuidelineExpert"]
