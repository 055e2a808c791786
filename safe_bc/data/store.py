"""The Parquet store: one file per episode plus a ``dataset.json`` (the only pyarrow user).

Layout of a dataset directory ``DIR``::

    DIR/dataset.json                    dataset-level metadata (also embedded in every file)
    DIR/episodes/episode-00000.parquet  one file per episode, one row per step
    DIR/frame-cache/frames-<key>.npy    the decoded frames, written by the first streamed
                                        load (:func:`frame_cache`); derived, safe to delete
    DIR/frame-cache/frames-<key>.sha256 their SHA-256, checked when the cache is opened

Columns (the contract later work and outside readers rely on): ``episode_id``,
``step``, ``seed``, ``observation`` (binary PNG or raw bytes of a ``96x96x3 uint8``
frame, or a float32 list for vector envs; ``dataset.json`` says which),
``action`` (float32 list: the action the expert chose), ``executed_action`` (what
was executed, differs under perturbation), ``reward``, ``terminated``,
``truncated``, ``safety_<dim>`` and ``cost_<dim>`` per safety dimension
(``left``, ``front``, ``right`` for CarRacing), ``warmup`` and ``offroad``.

Every write goes to a temporary file in the same directory and is renamed into
place, so a crash never leaves a partial episode behind.

A dataset is what its metadata says. Every episode file embeds the ``dataset.json`` of the
collection that wrote it (seed, expert, perturbation, encoding: the identity
:meth:`DatasetMeta.identity`), and reading checks it against the folder's ``dataset.json``:
an episode of another collection (another ``--seed``) is refused naming the file. Reading
also refuses, naming the file, an episode whose ``episode_id`` column is not the id in its
name (a copy under a second name), whose ``step`` column is not ``0..n-1`` (duplicated or
missing rows), two files holding the episode of the same env seed, and non-finite actions or
(vector) observations. A file without embedded metadata (written by another tool) is
accepted on its schema alone, as before.

Every episode file also embeds a SHA-256 of each of its columns (:data:`DIGEST_KEY`), and
reading a column checks it: a flipped bit that still decodes (a changed action, reward or
cost) is refused naming the file. Files written before it are accepted without the check.
"""

from __future__ import annotations

import hashlib
import json
import re
import sys
from collections.abc import Iterable, Iterator, Mapping, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from safe_bc.data.atomic import atomic_write, write_text_atomic
from safe_bc.data.codec import Encoding, decode_frames, encode_frames
from safe_bc.data.demos import Demonstrations
from safe_bc.data.episode import Episode
from safe_bc.data.frames import FrameFile, FrameFileError, checksum_path, write_frame_file

META_FILE = "dataset.json"
EPISODE_DIR = "episodes"
META_KEY = b"safe_bc"
DIGEST_KEY = b"safe_bc_digest"
"""Schema-metadata key of an episode file's checksums: JSON ``{column: SHA-256}`` of each
column's values (:func:`_column_digests`), written by :func:`write_episode` and checked by
every read of the columns (a file without it, written before or by another tool, is not)."""


class DatasetError(Exception):
    """A dataset is missing, unreadable, or not what it should be. The message is one line."""


@dataclass(frozen=True)
class DatasetMeta:
    """Dataset-level metadata, written once to ``dataset.json`` and into every file."""

    env_id: str
    """Environment id, e.g. ``CarRacing-v3``."""
    obs_encoding: Encoding
    """How the ``observation`` column is stored."""
    obs_shape: tuple[int, ...]
    """Shape of one decoded observation, e.g. ``(96, 96, 3)``."""
    safety_dims: tuple[str, ...]
    """Safety dimensions, the suffixes of the ``safety_*``/``cost_*`` columns."""
    seed: int
    """The collection's ``--seed``."""
    max_steps: int | None
    """Episode step cap used for collection (``None``: the env's time limit)."""
    expert: dict[str, Any]
    """The expert's configuration."""
    perturbation: dict[str, Any]
    """The perturbation's configuration."""
    provenance: dict[str, str] = field(default_factory=dict, compare=False)
    """Package version, git revision, creation time (not part of the dataset's identity)."""
    renderer: str | None = None
    """How the env drew the frames (CarRacing's ``EnvConfig.renderer``); ``None`` for tasks
    without renderers and for datasets collected before it was recorded (2026-11-26; those
    CarRacing sets were drawn by the renderer then called ``fast``, now ``exact``, unless
    collected for the raster ablation)."""
    action_bounds: tuple[tuple[float, ...], tuple[float, ...]] | None = field(
        default=None, compare=False
    )
    """``(low (A,), high (A,))`` of the env's action space; ``None`` in datasets collected
    before it was recorded (then the task registry has it). Fixed by ``env_id``, so not part
    of the identity."""

    def to_json(self) -> str:
        """Serialise to JSON."""
        return json.dumps(asdict(self), indent=2, sort_keys=True)

    @classmethod
    def from_json(cls, text: str, source: str = "dataset.json") -> DatasetMeta:
        """Parse the JSON written by :meth:`to_json`."""
        try:
            raw = json.loads(text)
            raw["obs_shape"] = tuple(raw["obs_shape"])
            raw["safety_dims"] = tuple(raw["safety_dims"])
            if raw.get("action_bounds") is not None:
                low, high = raw["action_bounds"]
                raw["action_bounds"] = (tuple(map(float, low)), tuple(map(float, high)))
            return cls(**raw)
        except (ValueError, TypeError, KeyError) as e:
            raise DatasetError(f"{source}: malformed dataset metadata ({e})") from None

    def identity(self) -> dict[str, Any]:
        """The fields that must agree for two runs to add to the same dataset."""
        d = asdict(self)
        d.pop("provenance")
        d.pop("action_bounds")
        if d["renderer"] is None:  # (identities of sets collected before it was recorded)
            d.pop("renderer")
        return json.loads(json.dumps(d))


def episode_path(root: Path, episode_id: int) -> Path:
    """Where episode ``episode_id`` of the dataset at ``root`` lives."""
    return Path(root) / EPISODE_DIR / f"episode-{episode_id:05d}.parquet"


def _schema(meta: DatasetMeta) -> pa.Schema:
    obs_type = pa.list_(pa.float32()) if meta.obs_encoding == "vector" else pa.binary()
    fields = [
        pa.field("episode_id", pa.int64()),
        pa.field("step", pa.int32()),
        pa.field("seed", pa.int64()),
        pa.field("observation", obs_type),
        pa.field("action", pa.list_(pa.float32())),
        pa.field("executed_action", pa.list_(pa.float32())),
        pa.field("reward", pa.float32()),
        pa.field("terminated", pa.bool_()),
        pa.field("truncated", pa.bool_()),
    ]
    fields += [pa.field(f"safety_{d}", pa.float32()) for d in meta.safety_dims]
    fields += [pa.field(f"cost_{d}", pa.float32()) for d in meta.safety_dims]
    fields += [pa.field("warmup", pa.bool_()), pa.field("offroad", pa.bool_())]
    return pa.schema(fields, metadata={META_KEY: meta.to_json().encode()})


def write_table_atomic(path: Path, frame: Any, metadata: dict[str, Any] | None = None) -> None:
    """Write a pandas DataFrame to Parquet atomically, with JSON ``metadata`` embedded.

    Result tables (evaluations, studies) go through here so that each file records
    the command, seeds and code revision that made it. A table under the checkout's
    ``results/`` is refused from a dirty git tree unless ``$SAFE_BC_ALLOW_DIRTY`` gives a
    reason, which is then recorded under ``"dirty_tree"``
    (:func:`safe_bc.data.provenance.check_result_write`). Metadata that records no provenance gets
    this run's (:func:`safe_bc.data.provenance.with_provenance`: revision, CPU, torch's kernels).
    """
    from safe_bc.data.provenance import result_metadata
    from safe_bc.report import units_of

    metadata = result_metadata(path, metadata)
    table = pa.Table.from_pandas(frame, preserve_index=False)
    units = units_of(table.column_names)
    fields = [
        f.with_metadata({**(f.metadata or {}), b"unit": units[f.name].encode()})
        if f.name in units
        else f
        for f in table.schema
    ]
    merged = {
        **(table.schema.metadata or {}),
        META_KEY: json.dumps(metadata, sort_keys=True, default=str).encode(),
    }
    table = table.cast(pa.schema(fields, metadata=merged))
    with atomic_write(path) as f:
        pq.write_table(table, f, compression="zstd")


def write_tables_atomic(
    folder: Path, frames: Mapping[str, Any], metadata: dict[str, Any] | None = None
) -> None:
    """The result tables of one step, ``folder/<name>.parquet`` for each of ``frames``, each
    written as :func:`write_table_atomic` writes it, with the same ``metadata``."""
    for name, frame in frames.items():
        write_table_atomic(Path(folder) / f"{name}.parquet", frame, metadata)


def column_units(path: Path) -> dict[str, str]:
    """The units a result table's columns carry (:func:`write_table_atomic` puts each one,
    :func:`safe_bc.report.units_of`, in its column's Arrow field metadata as ``unit``)."""
    schema = pq.read_schema(path)
    return {
        f.name: f.metadata[b"unit"].decode() for f in schema if f.metadata and b"unit" in f.metadata
    }


def read_table(path: Path) -> tuple[Any, dict[str, Any]]:
    """Read a table written by :func:`write_table_atomic`: ``(DataFrame, metadata)``."""
    path = Path(path)
    if not path.exists():
        raise DatasetError(f"{path}: no such file")
    try:
        table = pq.read_table(path)
    except (pa.ArrowException, OSError) as e:
        raise DatasetError(f"{path}: not a readable Parquet file ({_first_line(e)})") from None
    raw = (table.schema.metadata or {}).get(META_KEY)
    meta = json.loads(raw) if raw else {}
    return table.to_pandas(), meta


def read_table_metadata(path: Path) -> dict[str, Any]:
    """The JSON metadata :func:`write_table_atomic` embedded in ``path`` (``{}`` if none),
    without reading the rows."""
    path = Path(path)
    try:
        schema_meta = pq.read_metadata(path).metadata or {}
    except (pa.ArrowException, OSError) as e:
        raise DatasetError(f"{path}: not a readable Parquet file ({_first_line(e)})") from None
    raw = schema_meta.get(META_KEY)
    return json.loads(raw) if raw else {}


def init_dataset(root: Path, meta: DatasetMeta) -> DatasetMeta:
    """Create ``root`` for ``meta`` or check that an existing dataset there matches it.

    Returns the metadata on disk (the original provenance is kept on resume).
    """
    root = Path(root)
    meta_path = root / META_FILE
    if meta_path.exists():
        existing = read_meta(root)
        if existing.identity() != meta.identity():
            diff = [
                k for k in meta.identity() if existing.identity().get(k) != meta.identity().get(k)
            ]
            raise DatasetError(
                f"{meta_path}: dataset was collected with different settings "
                f"({', '.join(diff)}); choose another output directory"
            )
        return existing
    root.mkdir(parents=True, exist_ok=True)
    write_text_atomic(meta_path, meta.to_json())
    return meta


def read_meta(root: Path) -> DatasetMeta:
    """Read ``root/dataset.json``."""
    meta_path = Path(root) / META_FILE
    if not meta_path.exists():
        raise DatasetError(f"{root}: no dataset here (missing {META_FILE}); run `safe-bc collect`")
    return DatasetMeta.from_json(meta_path.read_text(), source=str(meta_path))


def check_dataset(root: Path, flag: str = "--demos") -> None:
    """Refuse, in one line naming the folder or the file, a path that is no demonstration set
    or a set with a damaged episode (every episode's schema, identity and column checksums
    read), before a command writes or starts anything; ``flag``: the option that named it."""
    root = Path(root)
    if root.exists() and not root.is_dir():
        raise DatasetError(f"{flag} {root}: a file, not a demonstration set folder")
    meta = read_meta(root)
    for episode_id in completed_episodes(root, meta):
        _read_episode_table(episode_path(root, episode_id))


def write_episode(root: Path, episode: Episode, meta: DatasetMeta) -> Path:
    """Encode ``episode`` and write it atomically to its file under ``root``."""
    if episode.safety_dims != meta.safety_dims:
        raise ValueError(f"episode safety dims {episode.safety_dims} != {meta.safety_dims}")
    n = len(episode)
    if meta.obs_encoding == "vector":
        obs = pa.array(list(episode.observations.astype(np.float32)), pa.list_(pa.float32()))
    else:
        obs = pa.array(encode_frames(episode.observations, meta.obs_encoding), pa.binary())
    cols: dict[str, Any] = {
        "episode_id": np.full(n, episode.episode_id, np.int64),
        "step": np.arange(n, dtype=np.int32),
        "seed": np.full(n, episode.seed, np.int64),
        "observation": obs,
        "action": pa.array(list(episode.actions.astype(np.float32)), pa.list_(pa.float32())),
        "executed_action": pa.array(
            list(episode.executed_actions.astype(np.float32)), pa.list_(pa.float32())
        ),
        "reward": episode.rewards.astype(np.float32),
        "terminated": episode.terminated,
        "truncated": episode.truncated,
    }
    for j, d in enumerate(meta.safety_dims):
        cols[f"safety_{d}"] = episode.safety[:, j].astype(np.float32)
    for j, d in enumerate(meta.safety_dims):
        cols[f"cost_{d}"] = episode.costs[:, j].astype(np.float32)
    cols["warmup"] = episode.warmup
    cols["offroad"] = episode.offroad
    table = pa.table(cols, schema=_schema(meta))
    digests = json.dumps(_column_digests(table), sort_keys=True).encode()
    table = table.replace_schema_metadata({**table.schema.metadata, DIGEST_KEY: digests})
    path = episode_path(root, episode.episode_id)
    with atomic_write(path) as f:
        pq.write_table(table, f, compression="zstd")
    return path


def _first_line(e: BaseException) -> str:
    return (str(e).strip().splitlines() or [type(e).__name__])[0]


def _column_digests(table: pa.Table) -> dict[str, str]:
    """``{column: SHA-256}`` of each column of ``table``: the Arrow IPC message of its values
    as one record batch (lengths, null counts, buffers; not the schema, whose list item names
    a Parquet round trip changes), the same for the same values however read or chunked."""
    out = {}
    for name in table.column_names:
        batches = table.select([name]).combine_chunks().to_batches()
        h = hashlib.sha256()
        for batch in batches:  # one, or none for no rows
            h.update(batch.serialize())
        out[name] = h.hexdigest()
    return out


def _check_digests(path: Path, table: pa.Table) -> None:
    """The columns of ``table`` (read from ``path``) must match the checksums
    :func:`write_episode` embedded in it; a file without them is accepted."""
    raw = (table.schema.metadata or {}).get(DIGEST_KEY)
    if raw is None:
        return
    try:
        recorded = json.loads(raw)
        if not isinstance(recorded, dict):
            raise ValueError("not a mapping")
    except ValueError as e:
        raise DatasetError(f"{path}: malformed column checksums ({_first_line(e)})") from None
    got = _column_digests(table)
    bad = [name for name in table.column_names if recorded.get(name) != got[name]]
    if bad:
        raise DatasetError(
            f"{path}: its data do not match the checksum written with it (damaged); column(s) "
            f"{', '.join(bad)} changed: restore the file or collect the dataset again"
        )


def _read_episode_table(path: Path, columns: Sequence[str] | None = None) -> pa.Table:
    """Columns ``columns`` (all: ``None``) of the episode file ``path``, their checksums
    checked."""
    try:
        table = pq.read_table(path, columns=None if columns is None else list(columns))
    except (pa.ArrowException, OSError) as e:
        raise DatasetError(f"{path}: not a readable Parquet file ({_first_line(e)})") from None
    _check_digests(path, table)
    return table


def _check_schema(path: Path, schema: pa.Schema, meta: DatasetMeta) -> None:
    expected = _schema(meta)
    missing = [f.name for f in expected if f.name not in schema.names]
    if missing:
        raise DatasetError(f"{path}: wrong schema, missing column(s) {', '.join(missing)}")
    for f in expected:
        got = schema.field(f.name).type
        if got != f.type:
            raise DatasetError(f"{path}: wrong schema, column {f.name} is {got}, expected {f.type}")


def _check_identity(path: Path, schema: pa.Schema, meta: DatasetMeta) -> None:
    """The dataset metadata embedded in an episode file must be the folder's (same identity:
    seed, expert, perturbation, encoding, ...). Files without it are accepted."""
    raw = (schema.metadata or {}).get(META_KEY)
    if raw is None:
        return
    own = DatasetMeta.from_json(raw.decode(errors="replace"), source=str(path)).identity()
    expected = meta.identity()
    if own != expected:
        diff = [k for k in expected if own.get(k) != expected.get(k)]
        detail = f"seed {own.get('seed')} vs {expected.get('seed')}" if "seed" in diff else ""
        raise DatasetError(
            f"{path}: episode of another collection than {META_FILE} says "
            f"({', '.join(diff)}{': ' + detail if detail else ''}); two collections were mixed "
            "in this folder: move the file out or collect again into an empty folder"
        )


def check_episode_file(path: Path, meta: DatasetMeta) -> None:
    """Open ``path``'s footer and check its schema and embedded dataset identity (cheap: no
    data is read)."""
    try:
        schema = pq.read_schema(path)
    except (pa.ArrowException, OSError) as e:
        raise DatasetError(f"{path}: not a readable Parquet file ({_first_line(e)})") from None
    _check_schema(path, schema, meta)
    _check_identity(path, schema, meta)


def _episode_id_of(path: Path) -> int | None:
    """The id in an episode file's name, or ``None`` when the name is not one
    :func:`episode_path` writes."""
    match = re.fullmatch(r"episode-(\d+)\.parquet", path.name)
    if match is None:
        return None
    episode_id = int(match.group(1))
    return episode_id if episode_path(path.parent, episode_id).name == path.name else None


def completed_episodes(root: Path, meta: DatasetMeta) -> list[int]:
    """Ids of the episodes already stored under ``root`` (each file's schema checked).

    Every ``*.parquet`` file in ``episodes/`` must be an episode file named as
    :func:`episode_path` names it; any other one (a stray export, a renamed copy) is an
    error naming it, rather than being silently left out of the dataset. Hidden files
    (``.``-prefixed, e.g. an interrupted write's temporary file) are skipped.
    """
    ep_dir = Path(root) / EPISODE_DIR
    if not ep_dir.exists():
        return []
    ids = []
    for path in sorted(ep_dir.glob("*.parquet")):
        if path.name.startswith("."):
            continue
        episode_id = _episode_id_of(path)
        if episode_id is None:
            raise DatasetError(
                f"{path}: not an episode file (episode files are named episode-NNNNN.parquet); "
                f"move it out of {ep_dir}"
            )
        check_episode_file(path, meta)
        ids.append(episode_id)
    return ids


def read_columns(root: Path, columns: Sequence[str]) -> dict[str, np.ndarray]:
    """The named scalar columns of every stored episode of ``root``, concatenated in episode
    order: ``{column: (T_total,)}`` (reads only those columns, not the frames)."""
    root = Path(root)
    meta = read_meta(root)
    ids = completed_episodes(root, meta)
    if not ids:
        raise DatasetError(f"{root}: dataset has no episodes")
    tables = [_read_episode_table(episode_path(root, i), columns) for i in ids]
    return {c: np.concatenate([t.column(c).to_numpy() for t in tables]) for c in columns}


def read_episode(path: Path, meta: DatasetMeta, observations: bool = True) -> Episode:
    """Read and decode one episode file. ``observations=False`` leaves the observation column
    unread (no decoding): the episode's observations are then ``(T, 0) uint8``, as a rollout
    that does not keep them records."""
    try:
        schema = pq.read_schema(path)
    except (pa.ArrowException, OSError) as e:
        raise DatasetError(f"{path}: not a readable Parquet file ({_first_line(e)})") from None
    _check_schema(path, schema, meta)
    _check_identity(path, schema, meta)
    wanted = None if observations else [c for c in schema.names if c != "observation"]
    table = _read_episode_table(path, wanted)
    n = table.num_rows
    if n == 0:
        raise DatasetError(f"{path}: episode has no steps")
    _check_rows(path, table)

    def col(name: str) -> np.ndarray:
        return table.column(name).to_numpy()

    def matrix(name: str) -> np.ndarray:
        flat = table.column(name).combine_chunks().flatten().to_numpy()
        return flat.reshape(n, -1).astype(np.float32)

    try:
        if not observations:
            obs = np.zeros((n, 0), np.uint8)
        elif meta.obs_encoding == "vector":
            obs = matrix("observation")
        else:
            obs = decode_frames(
                table.column("observation").to_pylist(), meta.obs_encoding, meta.obs_shape
            )
    except ValueError as e:
        raise DatasetError(f"{path}: bad observation data ({e})") from None
    actions, executed = matrix("action"), matrix("executed_action")
    for name, values in (("observation", obs), ("action", actions), ("executed_action", executed)):
        if values.dtype.kind == "f" and not np.isfinite(values).all():
            bad = int((~np.isfinite(values.reshape(n, -1))).any(axis=1).sum())
            raise DatasetError(f"{path}: {bad} step(s) with a non-finite {name} (NaN or inf)")
    return Episode(
        episode_id=int(col("episode_id")[0]),
        seed=int(col("seed")[0]),
        observations=obs,
        actions=actions,
        executed_actions=executed,
        rewards=col("reward").astype(np.float32),
        terminated=col("terminated").astype(bool),
        truncated=col("truncated").astype(bool),
        safety=np.stack([col(f"safety_{d}") for d in meta.safety_dims], 1).astype(np.float32),
        costs=np.stack([col(f"cost_{d}") for d in meta.safety_dims], 1).astype(np.float32),
        warmup=col("warmup").astype(bool),
        offroad=col("offroad").astype(bool),
        safety_dims=meta.safety_dims,
    )


def _check_rows(path: Path, table: pa.Table) -> None:
    """One episode per file, named by its id, with steps ``0..n-1`` once each."""
    ids = np.unique(table.column("episode_id").to_numpy())
    named = _episode_id_of(path)
    if len(ids) != 1 or (named is not None and int(ids[0]) != named):
        held = ", ".join(str(int(i)) for i in ids[:5])
        raise DatasetError(
            f"{path}: holds episode {held}, not the episode its name says (a copy under a "
            "second name?); move it out"
        )
    steps = table.column("step").to_numpy()
    if not np.array_equal(steps, np.arange(len(steps))):
        dup = len(steps) - len(np.unique(steps))
        what = f"{dup} duplicated (episode_id, step) row(s)" if dup else "steps out of order"
        raise DatasetError(f"{path}: {what}; the step column must be 0..{len(steps) - 1}")


def read_episodes(
    root: Path, ids: Iterable[int] | None = None, observations: bool = True
) -> list[Episode]:
    """Read the episodes of the dataset at ``root`` (all, or the given ids) in id order
    (``observations=False``: without their observations, see :func:`read_episode`)."""
    meta = read_meta(root)
    return _read_episodes(Path(root), meta, completed_episodes(root, meta), ids, observations)


def _read_episodes(
    root: Path,
    meta: DatasetMeta,
    stored: Sequence[int],
    ids: Iterable[int] | None,
    observations: bool,
) -> list[Episode]:
    """:func:`read_episodes` with the dataset's metadata and stored episode ids read."""
    if not stored:
        raise DatasetError(f"{root}: dataset has no episodes; run `safe-bc collect`")
    wanted = stored if ids is None else sorted(ids)
    missing = sorted(set(wanted) - set(stored))
    if missing:
        raise DatasetError(f"{root}: missing episode(s) {missing}")
    episodes = [read_episode(episode_path(root, i), meta, observations) for i in wanted]
    first: dict[int, int] = {}
    for ep in episodes:  # every episode of a collection has its own env seed
        other = first.setdefault(ep.seed, ep.episode_id)
        if other != ep.episode_id:
            raise DatasetError(
                f"{episode_path(root, ep.episode_id)}: the same episode (env seed {ep.seed}) as "
                f"{episode_path(root, other).name}: a duplicated episode; move one out"
            )
    return episodes


FrameMode = Literal["memory", "stream"]
"""Where :func:`load_demonstrations` keeps a frame dataset's decoded frames: ``memory``, one
``(N, H, W, 3) uint8`` array (every frame resident); ``stream``, a :class:`FrameFile` under the
dataset folder that training reads a batch's rows from (see :func:`frame_cache`)."""

DEFAULT_FRAMES: FrameMode = "stream"
"""The frame mode of :func:`load_demonstrations` (``make bench``'s ``stream`` case: the
same training speed, peak RSS no longer growing with the number of episodes)."""

FRAME_CACHE_DIR = "frame-cache"
"""Folder of a dataset holding its decoded-frame file (``frames-<content key>.npy``)."""


def load_demonstrations(root: Path, frames: FrameMode = DEFAULT_FRAMES) -> Demonstrations:
    """Read a whole dataset into the flat arrays used for training.

    ``frames="stream"`` (frame datasets; vectors are always in memory): the observations are a
    :class:`FrameFile` of the dataset's decoded frames (:func:`frame_cache`), which gives the
    same arrays for the same rows as ``"memory"`` and so the same batches and weights."""
    _check_frames(frames)
    root = Path(root)
    meta = read_meta(root)
    return _load(root, meta, completed_episodes(root, meta), frames)


def read_demonstrations(
    root: Path, frames: FrameMode = DEFAULT_FRAMES
) -> tuple[Demonstrations, dict[str, Any]]:
    """The dataset at ``root`` loaded for training (:func:`load_demonstrations`) with the record
    a result table keeps of it (:func:`dataset_record`): ``(demonstrations, record)``, its
    metadata and episode files listed once for both."""
    _check_frames(frames)
    root = Path(root)
    meta = read_meta(root)
    ids = completed_episodes(root, meta)
    record = _record(root, meta, ids)
    return _load(root, meta, ids, frames), record


def _check_frames(frames: str) -> None:
    if frames not in ("memory", "stream"):
        raise ValueError(f"frames must be 'memory' or 'stream', not {frames!r}")


def _load(
    root: Path, meta: DatasetMeta, stored: Sequence[int], frames: FrameMode
) -> Demonstrations:
    """:func:`load_demonstrations` with the dataset's metadata and stored episode ids read."""
    stream = frames == "stream" and meta.obs_encoding != "vector"
    episodes = _read_episodes(root, meta, stored, None, observations=not stream)
    source = None
    if stream:
        ids, lengths = [ep.episode_id for ep in episodes], [len(ep) for ep in episodes]
        source = frame_cache(root, meta, ids, lengths)
    return Demonstrations.from_episodes(episodes, observations=source)


def content_key(root: Path, ids: Sequence[int]) -> str:
    """A hash of the dataset's ``dataset.json`` and the bytes of episode files ``ids``
    (reads them in 1 MiB pieces): any rewritten, added or removed episode changes it."""
    h = hashlib.blake2b(digest_size=16)
    h.update((Path(root) / META_FILE).read_bytes())
    for i in ids:
        path = episode_path(root, i)
        h.update(f"\0{path.name}\0{path.stat().st_size}\0".encode())
        with open(path, "rb") as f:
            while piece := f.read(2**20):
                h.update(piece)
    return h.hexdigest()


def data_digest(root: Path) -> str:
    """The content digest of the dataset at ``root``: SHA-256 over its collector settings
    (:meth:`DatasetMeta.identity`) and, episode by episode in id order, every column's values
    (the Arrow IPC bytes of the file's table with its schema metadata dropped).

    It names the data, not the files: the provenance embedded in ``dataset.json`` and in every
    episode file (creation time, revision) is left out, so the same collection made again on
    another clone (same seeds, settings and package versions) has the same digest, and any
    changed value, episode added or removed, or other setting changes it. Every file is read
    whole (a few MB for the default CarRacing set)."""
    meta = read_meta(root)
    return _digest(Path(root), meta, completed_episodes(root, meta))


def _digest(root: Path, meta: DatasetMeta, ids: Sequence[int]) -> str:
    h = hashlib.sha256(json.dumps(meta.identity(), sort_keys=True).encode())
    for i in ids:
        path = episode_path(root, i)
        try:
            table = pq.read_table(path).replace_schema_metadata(None).combine_chunks()
        except (pa.ArrowException, OSError) as e:
            raise DatasetError(f"{path}: not a readable Parquet file ({_first_line(e)})") from None
        sink = pa.BufferOutputStream()
        with pa.ipc.new_stream(sink, table.schema) as writer:
            writer.write_table(table)
        h.update(f"\0{i}\0".encode())
        h.update(sink.getvalue().to_pybytes())
    return "sha256:" + h.hexdigest()


def dataset_record(root: Path) -> dict[str, Any]:
    """What a result table records of a dataset it read: its path, content digest
    (:func:`data_digest`), episode count and collector settings (:meth:`DatasetMeta.identity`)."""
    root = Path(root)
    meta = read_meta(root)
    return _record(root, meta, completed_episodes(root, meta))


def _record(root: Path, meta: DatasetMeta, ids: Sequence[int]) -> dict[str, Any]:
    """:func:`dataset_record` with the dataset's metadata and stored episode ids read."""
    return {
        "path": str(root),
        "digest": _digest(root, meta, ids),
        "episodes": len(ids),
        "collector": meta.identity(),
    }


def collection_mismatch(
    root: Path, expected: DatasetMeta, episodes: int | None = None
) -> str | None:
    """How the dataset at ``root`` differs from a collection with metadata ``expected`` and
    ``episodes`` episodes (:func:`settings_mismatch`); ``None`` when it does not, or when
    there is no dataset at ``root``."""
    root = Path(root)
    if not (root / META_FILE).exists():
        return None
    stored = read_meta(root)
    return settings_mismatch(stored, len(completed_episodes(root, stored)), expected, episodes)


def settings_mismatch(
    stored: DatasetMeta, stored_episodes: int, expected: DatasetMeta, episodes: int | None
) -> str | None:
    """How a dataset of ``stored_episodes`` episodes collected with ``stored`` differs from a
    collection with ``expected`` and ``episodes`` episodes: one line naming each field, stored
    -> expected, or ``None``. Fewer episodes than ``episodes`` is not a difference (an
    interrupted collection resumes)."""
    have, wanted = _flat(stored.identity()), _flat(expected.identity())
    keys = list(dict.fromkeys([*wanted, *have]))
    diff = [f"{k} {_short(have.get(k))} -> {_short(wanted.get(k))}" for k in keys
            if have.get(k) != wanted.get(k)]  # fmt: skip
    if episodes is not None and stored_episodes > episodes:
        diff.append(f"episodes {stored_episodes} -> {episodes}")
    return "; ".join(diff) or None


def _flat(record: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    """Nested settings as dotted keys (``expert.max_speed``), so a message names the field.

    >>> _flat({"a": 1, "b": {"c": 2}})
    {'a': 1, 'b.c': 2}
    """
    out: dict[str, Any] = {}
    for k, v in record.items():
        if isinstance(v, dict):
            out.update(_flat(v, f"{prefix}{k}."))
        else:
            out[f"{prefix}{k}"] = v
    return out


def _short(value: Any) -> str:
    """A setting's value for a one-line message (JSON, cut at 60 characters)."""
    text = json.dumps(value, sort_keys=True, default=str)
    return text if len(text) <= 60 else text[:57] + "..."


def frame_cache(
    root: Path, meta: DatasetMeta, ids: Sequence[int], lengths: Sequence[int]
) -> FrameFile:
    """The decoded frames of episodes ``ids`` (of ``lengths`` steps) of the dataset at
    ``root``, in order, as a :class:`FrameFile`
    ``root/frame-cache/frames-<content_key>.npy``.

    Written on first use, one decoded episode at a time and atomically (a reader never sees
    a partial file); another dataset content (an episode rewritten, added or removed) has
    another key, so its file is written anew and the folder's older ones are deleted. A file
    of the right name whose size or header is wrong (truncated) is written again. Two
    processes writing at once each write a whole file; the last rename wins (same bytes).
    Opening checks the file against the SHA-256 written beside it (:meth:`FrameFile.verify`,
    one read of the file): a file whose frames were altered is written again, saying so on
    stderr, as is one without a checksum (written before it was recorded, or the writer
    stopped between the two files).
    """
    root = Path(root)
    shape = (int(sum(lengths)), *meta.obs_shape)
    name = f"frames-{content_key(root, ids)}.npy"
    places = [root / FRAME_CACHE_DIR / name, user_cache_dir() / FRAME_CACHE_DIR / name]
    for path in places:
        if path.exists():
            try:
                cached = FrameFile(path, shape)
                cached.verify()
                return cached
            except FrameFileError as e:  # truncated, damaged or unverifiable: written again
                if checksum_path(path).exists():
                    print(f"{e}; writing the decoded-frame cache again", file=sys.stderr)

    def decoded() -> Iterator[np.ndarray]:
        for i, n in zip(ids, lengths, strict=True):
            ep = read_episode(episode_path(root, i), meta)
            if len(ep) != n:
                raise DatasetError(f"{episode_path(root, i)}: changed while being read")
            yield ep.observations

    errors = []
    for path in places:  # beside the dataset; where it is read-only, in the user's cache
        try:
            write_frame_file(path, shape, decoded())
        except OSError as e:
            errors.append(f"{path}: {_first_line(e)}")
            continue
        for old in [*path.parent.glob("frames-*.npy"), *path.parent.glob("frames-*.sha256")]:
            if old not in (path, checksum_path(path)) and path.parent == places[0].parent:
                old.unlink(missing_ok=True)
        return FrameFile(path, shape)
    raise DatasetError(
        f"cannot write the decoded-frame cache ({'; '.join(errors)}); make the dataset folder "
        "or $SAFE_BC_CACHE writable, or load it with frames='memory'"
    )


def user_cache_dir() -> Path:
    """Where derived files go when a dataset's own folder is read-only: ``$SAFE_BC_CACHE``,
    else ``$XDG_CACHE_HOME/safe_bc``, else ``~/.cache/safe_bc``."""
    import os

    if os.environ.get("SAFE_BC_CACHE"):
        return Path(os.environ["SAFE_BC_CACHE"])
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "safe_bc"


# --- experiment storage: the pyarrow filesystems Ray Tune keeps a study on -----------------


def subfolders(fs: Any, folder: str, prefix: str = "") -> list[tuple[str, str]]:
    """``(path, name)`` of the folders directly inside ``folder`` on the ``pyarrow.fs``
    filesystem ``fs`` whose name starts with ``prefix`` (none when ``folder`` is absent)."""
    import pyarrow.fs as pafs

    infos = fs.get_file_info(pafs.FileSelector(folder, allow_not_found=True))
    return [
        (i.path, i.base_name)
        for i in infos
        if i.type == pafs.FileType.Directory and i.base_name.startswith(prefix)
    ]


def storage_folders(uri: str, prefix: str = "") -> tuple[Any, list[tuple[str, str]]]:
    """The filesystem of ``uri`` (a local path or e.g. ``s3://...``) and
    :func:`subfolders` of it."""
    import pyarrow.fs as pafs

    fs, root = pafs.FileSystem.from_uri(uri)
    return fs, subfolders(fs, root, prefix)


def delete_storage_tree(uri: str) -> None:
    """Delete the folder at ``uri`` (a local path or a URI) with everything in it, if present."""
    import pyarrow.fs as pafs

    fs, path = pafs.FileSystem.from_uri(uri)
    if fs.get_file_info(path).type != pafs.FileType.NotFound:
        fs.delete_dir(path)


def is_local_filesystem(fs: Any) -> bool:
    """Whether the ``pyarrow.fs`` filesystem ``fs`` is this machine's disk."""
    import pyarrow.fs as pafs

    return isinstance(fs, pafs.LocalFileSystem)
