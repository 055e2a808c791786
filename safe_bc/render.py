"""Pictures of episodes: videos with the safety readings drawn in, and track maps.

What is drawn over a frame, where the agent is and what the map shows are the task's
(:class:`safe_bc.tasks.Drawing`, ``TaskSpec.drawing``; CarRacing's is
:mod:`safe_bc.tasks.carracing.draw`: its three safety rays); a task without a drawing cannot
be rendered. The rest is here:

* :func:`render_episode` rolls a policy out on one track and writes an MP4 (or a GIF when
  the file name ends in ``.gif``): each frame is upscaled (4x by default) and the task's
  safety readings are drawn over it, one colour per dimension: green while the dimension
  is outside the critical zone, orange inside it (``c_s >= d_s - eps``), red beyond the
  limit (``c_s > d_s``, a violation) and grey during the warm-up (not scored); without a
  zone cyan. The frame's border shows the combined critical-zone state
  (the selection's ``combine`` rule) and a header line the step, distances and state.
* :func:`draw_paths` draws the track seen from above (``env.unwrapped.road_poly``) with
  each policy's driven path coloured by its safety distance (the smallest of left, front
  and right, in pixels), one panel per policy, e.g. the expert beside the agent;
  :func:`render_paths` rolls the policies out on one track and calls it.

Videos are encoded by imageio (its ffmpeg plugin, whose binary ships in the
``imageio-ffmpeg`` wheel; GIFs by its Pillow plugin). CarRacing runs at 50 steps/s.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import gymnasium as gym
import numpy as np

from safe_bc.data.episode import Episode
from safe_bc.policy import Policy
from safe_bc.progress import progress_bar
from safe_bc.rollout.episode import run_episode
from safe_bc.selection import DEFAULT_EPS, CriticalZone
from safe_bc.tasks.env_config import DEFAULT_RENDERER
from safe_bc.tasks.registry import DEFAULT_TASK, Drawing, Task, TaskSpec, spec_of, task_defaults

FPS = 50
"""CarRacing's simulation rate (steps per second), the default video frame rate."""
HEADER = 32
"""Height in pixels of the text strip above each upscaled frame."""

# RGB colours
GREEN = (40, 220, 40)
ORANGE = (255, 150, 0)
RED = (235, 30, 30)
GREY = (150, 150, 150)
CYAN = (0, 220, 230)
WHITE = (255, 255, 255)
MAGENTA = (230, 40, 230)
"""The inner border of a frame on which the expert acted (a recommender's handover)."""
STATE_COLOURS = {"safe": GREEN, "critical": ORANGE, "violation": RED, "warmup": GREY, "": CYAN}


@dataclass(frozen=True)
class Trace:
    """One rendered episode: the stored episode plus the car's position at every step."""

    episode: Episode
    """Observations, actions, safety, costs, warm-up flags (``T`` steps)."""
    positions: np.ndarray
    """``(T, 2)`` world coordinates of the car's hull when each observation was seen."""
    road: list[np.ndarray]
    """The road tiles, ``(4, 2)`` world-coordinate polygons."""
    label: str
    """Name of the policy (panel / video title)."""
    task: Task = DEFAULT_TASK
    """The task the episode ran on (its drawing draws it)."""


def drawing_of(spec: TaskSpec) -> Drawing:
    """The task's drawing; a task without one cannot be rendered (one-line error)."""
    if spec.drawing is None:
        raise ValueError(
            f"task {spec.name!r} cannot be rendered: its TaskSpec has no drawing "
            "(safe_bc.tasks.Drawing)"
        )
    return spec.drawing


class _Recorder:
    """A policy that remembers where the car was each time it was asked for an action."""

    def __init__(self, policy: Policy, drawing: Drawing, bar: Any = None) -> None:
        self.policy = policy
        self.drawing = drawing
        self.positions: list[tuple[float, float]] = []
        self.bar = bar  # a progress bar advanced once a step, or None

    def reset(self, env: gym.Env, rng: np.random.Generator) -> None:
        self.positions.clear()
        self.policy.reset(env, rng)

    def see(self, info: dict) -> None:
        """Pass each state's ``info`` on to a policy that reads it (a handover)."""
        see = getattr(self.policy, "see", None)
        if see is not None:
            see(info)

    def act(self, obs: np.ndarray, env: gym.Env) -> np.ndarray:
        self.positions.append(self.drawing.position(env))
        if self.bar is not None:
            self.bar.update(1)
        return self.policy.act(obs, env)


def record(
    policy: Policy,
    seed: int,
    *,
    label: str = "policy",
    max_steps: int | None = None,
    renderer: str = DEFAULT_RENDERER,
    task: Task = DEFAULT_TASK,
    progress: bool = False,
) -> Trace:
    """Roll ``policy`` out on ``task``'s track ``seed`` (``env.reset(seed=seed)``), keeping
    frames and positions. The policy's randomness is seeded with ``seed`` as in evaluation.
    ``progress``: a bar over the steps (on a terminal)."""
    from safe_bc.tasks import make_env

    spec = task_defaults(task, renderer)  # type: ignore[arg-type]
    drawing = drawing_of(spec)
    env = make_env(spec.env)
    cap = getattr(env.spec, "max_episode_steps", None)
    total = max_steps if cap is None else min(cap, max_steps or cap)
    bar = progress_bar(show=progress, total=total, desc=f"{label}: episode", unit="step")
    try:
        recorder = _Recorder(policy, drawing, bar)
        rng = np.random.default_rng(seed)
        episode = run_episode(env, recorder, seed, rng, max_steps=max_steps)
        ground = drawing.ground(env)
    finally:
        env.close()
        bar.close()
    return Trace(episode, np.asarray(recorder.positions, np.float64), ground, label, spec.name)


def dim_states(episode: Episode, zone: CriticalZone | None) -> np.ndarray:
    """``(T, S)`` state names per step and dimension: ``safe``, ``critical``, ``violation``,
    ``warmup`` (not scored), or ``""`` without a zone."""
    n, s = episode.safety.shape
    states = np.full((n, s), "" if zone is None else "safe", dtype=object)
    if zone is not None:
        from safe_bc.selection import critical_dims

        d = np.asarray(zone.limits, np.float64)
        states[critical_dims(episode.costs, d, zone.eps)] = "critical"
        states[np.asarray(episode.costs, np.float64) > d] = "violation"
    states[episode.warmup] = "warmup"
    return states


def frame_state(states: np.ndarray, combine: str = "any") -> str:
    """One step's state from its per-dimension states (worst first)."""
    if "warmup" in states:
        return "warmup"
    if "violation" in states:
        return "violation"
    critical = [s in ("critical", "violation") for s in states]
    if (all(critical) if combine == "all" else any(critical)) and len(critical):
        return "critical"
    return "safe" if "safe" in states else ""


def overlay(
    frame: np.ndarray,
    distances: np.ndarray,
    states: np.ndarray,
    state: str,
    text: str,
    scale: int = 4,
    drawing: Drawing | None = None,
) -> np.ndarray:
    """Upscale one frame and draw its safety readings (``drawing``'s overlay, the default
    task's without one), border and header.

    Returns:
        ``(HEADER + H * scale, W * scale, 3) uint8`` RGB.
    """
    drawing = drawing or drawing_of(task_defaults(DEFAULT_TASK))
    big = cv2.resize(frame, None, fx=scale, fy=scale, interpolation=cv2.INTER_NEAREST)
    drawing.overlay(big, distances, [STATE_COLOURS[str(s)] for s in states], scale)
    if state in ("critical", "violation"):
        cv2.rectangle(big, (0, 0), (big.shape[1] - 1, big.shape[0] - 1), STATE_COLOURS[state], 6)
    header = np.zeros((HEADER, big.shape[1], 3), np.uint8)
    colour = STATE_COLOURS.get(state, WHITE) if state else WHITE
    cv2.putText(header, text, (6, 21), cv2.FONT_HERSHEY_SIMPLEX, 0.45, colour, 1, cv2.LINE_AA)
    return np.concatenate([header, big], axis=0)


def annotated_frames(
    trace: Trace,
    zone: CriticalZone | None = None,
    scale: int = 4,
    deferred: np.ndarray | None = None,
    progress: bool = False,
) -> list[np.ndarray]:
    """Every frame of ``trace`` with its safety readings, border and header drawn in;
    ``deferred`` (``(T,) bool``, a recommender's handover) marks the frames on which the
    expert acted: "EXPERT" in the header and a magenta inner border. ``progress``: a bar."""
    drawing = drawing_of(task_defaults(trace.task))
    ep = trace.episode
    states = dim_states(ep, zone)
    combine = zone.combine if zone is not None else "any"
    frames = []
    steps = progress_bar(show=progress, iterable=range(len(ep)), desc="frames", unit="frame")
    for t in steps:
        state = frame_state(states[t], combine)
        expert_acted = deferred is not None and bool(deferred[t])
        text = f"{trace.label}  t={t}  {drawing.caption(ep.safety[t])}"
        if expert_acted:
            text += "  EXPERT"
        if state and state != "safe":
            text += f"  {state.upper()}"
        frame = overlay(ep.observations[t], ep.safety[t], states[t], state, text, scale, drawing)
        if expert_acted:
            h, w = frame.shape[:2]
            cv2.rectangle(frame, (8, HEADER + 8), (w - 9, h - 9), MAGENTA, 3)
        frames.append(frame)
    return frames


def write_video(
    frames: list[np.ndarray], out: str | Path, fps: float = FPS, progress: bool = False
) -> Path:
    """Write ``frames`` (RGB uint8) as MP4/other ffmpeg formats, or as a GIF for ``.gif``;
    ``progress``: a bar over the encoded frames (MP4)."""
    import imageio.v2 as imageio

    out = Path(out)
    if not frames:
        raise ValueError("no frames to write")
    out.parent.mkdir(parents=True, exist_ok=True)
    if out.suffix.lower() == ".gif":
        imageio.mimsave(out, frames, format="GIF", duration=1000.0 / fps, loop=0)
        return out
    with imageio.get_writer(out, format="FFMPEG", mode="I", fps=fps, macro_block_size=16) as w:
        for frame in progress_bar(show=progress, iterable=frames, desc="encode", unit="frame"):
            w.append_data(frame)
    return out


def render_episode(
    policy: Policy,
    seed: int,
    out: str | Path,
    *,
    label: str = "policy",
    zone: CriticalZone | None = None,
    max_steps: int | None = None,
    scale: int = 4,
    fps: float = FPS,
    task: Task = DEFAULT_TASK,
    progress: bool = False,
) -> Trace:
    """Roll ``policy`` out on ``task``'s track ``seed`` and write the annotated episode to
    ``out`` (one frame per step: the observation each action was chosen in); a policy that
    reports its handover (``flags``, :class:`safe_bc.rollout.handover.DeferringPolicy`) has the
    expert's steps marked. ``progress``: bars over the steps, frames and encoding."""
    trace = record(policy, seed, label=label, max_steps=max_steps, task=task, progress=progress)
    flags = getattr(policy, "flags", None)
    deferred = None if flags is None else np.asarray(flags, bool)
    frames = annotated_frames(trace, zone, scale, deferred, progress)
    write_video(frames, out, fps, progress)
    return trace


def render_recommender(
    out: str | Path,
    seed: int,
    recommender: str | Path,
    *,
    agent_seed: int | None = None,
    max_steps: int | None = None,
    scale: int = 4,
    fps: float = FPS,
    progress: bool = False,
) -> str:
    """What ``safe-bc render --recommender DIR`` does: one episode of the recommender (its
    agent of ``agent_seed``, default the first, with its handover) on track ``seed``, the
    critical zone drawn at ``d_s`` and the handover's width, the expert's steps marked;
    returns the line it prints."""
    from safe_bc.study.recommender import load_recommender

    rec = load_recommender(recommender)
    spec = task_defaults(rec.card.task)
    drawing_of(spec)
    handover = rec.card.handover_config
    width = spec.eps if handover is None else handover.width
    zone = CriticalZone(tuple(float(x) for x in rec.limits), width, "any")
    policy = rec.source(agent_seed).build()
    trace = render_episode(
        policy, seed, out, label="recommender", zone=zone, max_steps=max_steps,
        scale=scale, fps=fps, task=spec.name, progress=progress,
    )  # fmt: skip
    ep = trace.episode
    scored = ~ep.warmup
    flags = np.asarray(getattr(policy, "flags", np.zeros(len(ep), bool)), bool)
    line = f"{out}: {len(ep)} frames of the recommender on track seed {seed}"
    line += f", the expert acted on {int(flags.sum())} ({flags[scored].mean():.1%} of scored steps)"
    bad = zone.beyond(ep.costs) & scored
    return line + f", {int(bad.sum())} step(s) beyond d_s"


def draw_paths(
    traces: list[Trace], out: str | Path, *, zone: CriticalZone | None = None, title: str = ""
) -> Path:
    """One panel per trace: the ground from above (the task's drawing's), the driven path
    coloured by the smallest safety distance (grey during the warm-up), violations (with
    ``zone``) as red crosses. Colours share one scale across panels."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.collections import LineCollection, PolyCollection

    if not traces:
        raise ValueError("no traces to draw")
    drawing = drawing_of(task_defaults(traces[0].task))
    scored = [tr.episode.safety[~tr.episode.warmup].min(axis=1) for tr in traces]
    top = max((float(np.percentile(s, 95)) for s in scored if len(s)), default=1.0)
    norm = plt.Normalize(0.0, max(top, 1.0))
    fig, axes = plt.subplots(
        1, len(traces), figsize=(5.5 * len(traces) + 1, 5), squeeze=False, layout="constrained"
    )
    line = None
    for ax, trace in zip(axes[0], traces, strict=True):
        ep, xy = trace.episode, trace.positions
        ax.add_collection(PolyCollection(trace.road, facecolors="0.55", edgecolors="none"))
        d = ep.safety.min(axis=1)
        segments = np.stack([xy[:-1], xy[1:]], axis=1)
        warm = ep.warmup[:-1]
        ax.add_collection(LineCollection(segments[warm], colors="0.85", linewidths=1.5))
        line = LineCollection(segments[~warm], cmap="RdYlGn", norm=norm, linewidths=2.5)
        line.set_array(d[:-1][~warm])
        ax.add_collection(line)
        ax.plot(*xy[0], "o", color="k", ms=5, label="start")
        summary = f"{len(ep)} steps, reward {ep.total_reward:.0f}"
        if (~ep.warmup).any():
            summary += f", closest {d[~ep.warmup].min():.1f} {drawing.unit}"
        if zone is not None:
            bad = zone.beyond(ep.costs)
            bad &= ~ep.warmup
            if bad.any():
                ax.plot(*xy[bad].T, "x", color="red", ms=5, label="violation")
            summary += f", {int(bad.sum())} violation step(s)"
        ax.set_title(f"{trace.label}\n{summary}", fontsize=9)
        ax.set_aspect("equal")
        ax.autoscale_view()
        ax.set_xticks([])
        ax.set_yticks([])
        ax.legend(loc="lower right", fontsize=8)
    assert line is not None
    fig.colorbar(line, ax=list(axes[0]), shrink=0.8, label=drawing.scale_label)
    if title:
        fig.suptitle(title)
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out


def render_paths(
    policies: Mapping[str, Policy],
    seed: int,
    out: str | Path,
    *,
    zone: CriticalZone | None = None,
    max_steps: int | None = None,
    task: Task = DEFAULT_TASK,
    progress: bool = False,
) -> list[Trace]:
    """Roll each policy out on ``task``'s track ``seed`` and draw their paths side by side."""
    traces = [
        record(p, seed, label=name, max_steps=max_steps, task=task, progress=progress)
        for name, p in policies.items()
    ]
    draw_paths(traces, out, zone=zone, title=f"track seed {seed}")
    return traces


def zone_from_checkpoint(directory: str | Path) -> CriticalZone:
    """The critical zone (``d_s``, eps, combine) a ``safe-bc train`` checkpoint was selected
    with."""
    from safe_bc.data.store import read_table

    _, meta = read_table(Path(directory) / "selection.parquet")
    if "thresholds" not in meta:
        raise ValueError(f"{directory}/selection.parquet: no thresholds in its metadata")
    cfg = meta.get("config", {})
    return CriticalZone(
        np.asarray(meta["thresholds"], np.float64),
        float(cfg.get("eps", DEFAULT_EPS)),
        str(cfg.get("combine", "any")),
    )


def zone_from_demos(demos: str | Path, eps: float) -> CriticalZone:
    """``d_s``: the demonstrations' worst cost per dimension over the scored steps (reads
    only the cost and warm-up columns)."""
    from safe_bc.data.store import read_columns, read_meta
    from safe_bc.selection import thresholds

    dims = [f"cost_{d}" for d in read_meta(demos).safety_dims]
    cols = read_columns(Path(demos), [*dims, "warmup"])
    costs = np.stack([cols[c] for c in dims], 1)
    warmup = cols["warmup"].astype(bool)
    return CriticalZone(thresholds(costs, "max", valid=~warmup), eps)


def _checkpoint_env_id(directory: Path) -> str:
    from safe_bc.bc.checkpoint import read_checkpoint_meta

    default = task_defaults(DEFAULT_TASK).env.env_id
    return str(read_checkpoint_meta(directory).get("extra", {}).get("env_id", default))


def render_command(
    out: str | Path,
    seed: int,
    *,
    checkpoint: str | Path | None = None,
    expert: bool = False,
    paths: bool = False,
    demos: str | Path | None = None,
    eps: float | None = None,
    max_steps: int | None = None,
    scale: int = 4,
    fps: float = FPS,
    progress: bool = False,
) -> str:
    """What ``safe-bc render`` does; returns the line it prints (``progress``: bars).

    The task is the checkpoint's (else the demonstrations', else the default task); one
    without a drawing (``TaskSpec.drawing``) cannot be rendered. The agent is the
    checkpoint's net; the expert is the one recorded in the demonstrations' ``dataset.json``
    (``demos``, else the checkpoint's, else the task's default demonstrations when present;
    the task's default expert otherwise). The critical zone is the
    checkpoint's selection (``d_s``, eps, combine), else ``d_s`` of ``demos`` with ``eps``
    (default: the task's); without either the readings are drawn without states. ``paths`` draws the
    track map instead: the expert beside the agent (the expert alone without a checkpoint).
    """
    from safe_bc.data.store import read_meta
    from safe_bc.rollout.collect import build_expert, stored_expert_config

    if checkpoint is None and not (expert or paths):
        raise ValueError("render needs --checkpoint DIR (the agent) or --expert")
    zone = None
    spec = None
    if checkpoint is not None:
        checkpoint = Path(checkpoint)
        spec = spec_of(_checkpoint_env_id(checkpoint))
        drawing_of(spec)
        if (checkpoint / "selection.parquet").is_file():  # a study trial's has none
            zone = zone_from_checkpoint(checkpoint)
        if demos is None:
            from safe_bc.bc.checkpoint import read_checkpoint_meta

            recorded = read_checkpoint_meta(checkpoint).get("extra", {}).get("demos")
            demos = recorded if recorded and (Path(recorded) / "dataset.json").is_file() else None
    if demos is not None:
        demo_spec = spec_of(read_meta(demos).env_id)
        if spec is not None and demo_spec.name != spec.name:
            raise ValueError(f"{demos}: {demo_spec.name} demonstrations, not {spec.name}'s")
        spec = demo_spec
    spec = spec or task_defaults(DEFAULT_TASK)
    drawing_of(spec)
    if demos is None and (Path(spec.demos) / "dataset.json").is_file():
        demos = Path(spec.demos)
    if zone is None and demos is not None:
        zone = zone_from_demos(demos, spec.eps if eps is None else eps)
    if zone is not None and eps is not None:
        zone = CriticalZone(zone.limits, eps, zone.combine)
    expert_policy = build_expert(
        stored_expert_config(Path(demos)) if demos is not None else spec.expert
    )

    def agent() -> Policy:
        from safe_bc.bc.policy import BCPolicy

        assert checkpoint is not None
        return BCPolicy.from_checkpoint(checkpoint)

    if paths:
        policies = {"expert": expert_policy}
        if checkpoint is not None:
            policies["agent"] = agent()
        traces = render_paths(
            policies, seed, out, zone=zone, max_steps=max_steps, task=spec.name, progress=progress
        )
        drawn = ", ".join(f"{t.label} ({len(t.episode)} steps)" for t in traces)
        return f"{out}: paths of {drawn} on track seed {seed}"
    label = "expert" if expert else "agent"
    policy = expert_policy if expert else agent()
    trace = render_episode(
        policy,
        seed,
        out,
        label=label,
        zone=zone,
        max_steps=max_steps,
        scale=scale,
        fps=fps,
        task=spec.name,
        progress=progress,
    )
    ep = trace.episode
    scored = ~ep.warmup
    line = f"{out}: {len(ep)} frames of the {label} on track seed {seed}"
    if scored.any():
        line += f", closest {ep.safety[scored].min():.1f} {drawing_of(spec).closest}"
    if zone is not None:
        bad = zone.beyond(ep.costs) & scored
        line += f", {int(bad.sum())} violation step(s) (d_s of the demonstrations)"
    return line


__all__ = [
    "FPS",
    "CriticalZone",
    "Trace",
    "annotated_frames",
    "dim_states",
    "draw_paths",
    "drawing_of",
    "frame_state",
    "overlay",
    "record",
    "render_command",
    "render_episode",
    "render_paths",
    "render_recommender",
    "write_video",
    "zone_from_checkpoint",
    "zone_from_demos",
]
