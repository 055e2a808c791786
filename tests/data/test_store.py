"""The Parquet store: round trips, outside readers, schema and corruption errors."""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow as pa
import pytest

from safe_bc.data.episode import SAFETY_DIMS, Episode
from safe_bc.data.store import (
    DatasetError,
    DatasetMeta,
    completed_episodes,
    episode_path,
    init_dataset,
    load_demonstrations,
    read_columns,
    read_episode,
    read_episodes,
    read_table,
    write_episode,
    write_table_atomic,
)


def make_episode(episode_id: int, n: int = 12, seed: int = 0) -> Episode:
    rng = np.random.default_rng(episode_id)
    return Episode(
        episode_id=episode_id,
        seed=seed + episode_id,
        observations=rng.integers(0, 256, (n, 96, 96, 3), dtype=np.uint8),
        actions=rng.uniform(-1, 1, (n, 3)).astype(np.float32),
        executed_actions=rng.uniform(-1, 1, (n, 3)).astype(np.float32),
        rewards=rng.normal(size=n).astype(np.float32),
        terminated=np.arange(n) == n - 1,
        truncated=np.zeros(n, bool),
        safety=rng.uniform(0, 40, (n, 3)).astype(np.float32),
        costs=rng.uniform(0, 40, (n, 3)).astype(np.float32),
        warmup=np.arange(n) < 3,
        offroad=np.zeros(n, bool),
    )


def make_meta(encoding: str = "png", seed: int = 0) -> DatasetMeta:
    return DatasetMeta(
        env_id="CarRacing-v3",
        obs_encoding=encoding,  # type: ignore[arg-type]
        obs_shape=(96, 96, 3),
        safety_dims=SAFETY_DIMS,
        seed=seed,
        max_steps=None,
        expert={"type": "ExpertConfig"},
        perturbation={"mode": "none"},
        provenance={"git_revision": "test"},
    )


@pytest.mark.parametrize("encoding", ["png", "raw"])
def test_round_trip_is_lossless(tmp_path: Path, encoding: str) -> None:
    meta = init_dataset(tmp_path, make_meta(encoding))
    eps = [make_episode(i) for i in range(2)]
    for ep in eps:
        write_episode(tmp_path, ep, meta)
    back = read_episodes(tmp_path)
    for a, b in zip(eps, back, strict=True):
        for name in ("observations", "actions", "executed_actions", "safety", "costs", "warmup"):
            np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    demos = load_demonstrations(tmp_path)
    assert len(demos) == 24 and demos.observations.shape == (24, 96, 96, 3)


def test_outside_readers_see_the_contract(tmp_path: Path) -> None:
    meta = init_dataset(tmp_path, make_meta())
    write_episode(tmp_path, make_episode(0), meta)
    df = pd.read_parquet(tmp_path / "episodes")
    expected = {"episode_id", "step", "seed", "observation", "action", "executed_action"}
    expected |= {"reward", "terminated", "truncated", "warmup", "offroad"}
    expected |= {f"safety_{d}" for d in SAFETY_DIMS} | {f"cost_{d}" for d in SAFETY_DIMS}
    assert expected <= set(df.columns)
    assert len(df["action"].iloc[0]) == 3
    import duckdb

    rows = duckdb.sql(
        f"select count(*) from read_parquet('{tmp_path}/episodes/*.parquet')"
    ).fetchall()
    n = rows[0][0]
    assert n == 12


def test_wrong_schema_names_the_file(tmp_path: Path) -> None:
    meta = init_dataset(tmp_path, make_meta())
    write_episode(tmp_path, make_episode(0), meta)
    bad = episode_path(tmp_path, 1)
    pd.DataFrame({"episode_id": [1], "step": [0]}).to_parquet(bad)
    with pytest.raises(DatasetError, match=r"episode-00001\.parquet: wrong schema, missing"):
        completed_episodes(tmp_path, meta)


def test_truncated_file_names_the_file(tmp_path: Path) -> None:
    meta = init_dataset(tmp_path, make_meta())
    path = write_episode(tmp_path, make_episode(0), meta)
    path.write_bytes(path.read_bytes()[:500])
    with pytest.raises(DatasetError, match=r"episode-00000\.parquet: not a readable Parquet"):
        read_episodes(tmp_path)


def test_missing_dataset_is_clear(tmp_path: Path) -> None:
    with pytest.raises(DatasetError, match="no dataset here"):
        load_demonstrations(tmp_path / "nope")


def test_other_settings_are_not_mixed_in(tmp_path: Path) -> None:
    init_dataset(tmp_path, make_meta(seed=0))
    with pytest.raises(DatasetError, match=r"different settings.*seed"):
        init_dataset(tmp_path, make_meta(seed=1))


def test_failed_write_leaves_nothing(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    meta = init_dataset(tmp_path, make_meta())
    import pyarrow.parquet as pq

    def boom(table, sink, **kwargs):
        sink.write(b"partial")  # the open temporary file
        raise OSError("disk full")

    monkeypatch.setattr(pq, "write_table", boom)
    with pytest.raises(OSError, match="disk full"):
        write_episode(tmp_path, make_episode(0), meta)
    assert list((tmp_path / "episodes").iterdir()) == []


def test_result_table_keeps_its_metadata(tmp_path: Path) -> None:
    df = pd.DataFrame({"alpha": [0.0, 0.5], "reward": [1.0, 2.0]})
    write_table_atomic(tmp_path / "t.parquet", df, {"seed": 3, "git_revision": "abc"})
    back, meta = read_table(tmp_path / "t.parquet")
    pd.testing.assert_frame_equal(back, df)
    assert meta == {"seed": 3, "git_revision": "abc"}


def test_data_digest_names_the_data_not_the_files(tmp_path: Path) -> None:
    from dataclasses import replace

    from safe_bc.data.store import data_digest, dataset_record

    a, b = tmp_path / "a", tmp_path / "b"
    for root, when in ((a, "first"), (b, "second")):  # same data, other provenance
        meta = init_dataset(root, replace(make_meta(), provenance={"created": when}))
        for i in range(2):
            write_episode(root, make_episode(i), meta)
    assert data_digest(a) == data_digest(b)
    assert (a / "dataset.json").read_bytes() != (b / "dataset.json").read_bytes()
    record = dataset_record(a)
    assert record["digest"] == data_digest(a) and record["episodes"] == 2
    assert record["collector"] == make_meta().identity()
    # one changed value, or one episode more, is another dataset
    changed = make_episode(1)
    changed.rewards[3] += 1.0
    write_episode(b, changed, init_dataset(b, make_meta()))
    assert data_digest(b) != data_digest(a)
    write_episode(a, make_episode(2), init_dataset(a, make_meta()))
    assert data_digest(a) != record["digest"]


def test_collection_mismatch_names_each_differing_setting(tmp_path: Path) -> None:
    from dataclasses import replace

    from safe_bc.data.store import collection_mismatch

    meta = init_dataset(tmp_path, make_meta())
    for i in range(3):
        write_episode(tmp_path, make_episode(i), meta)
    assert collection_mismatch(tmp_path, make_meta(), 3) is None
    assert collection_mismatch(tmp_path, make_meta(), 5) is None  # interrupted: resumes
    assert collection_mismatch(tmp_path, make_meta(), 2) == "episodes 3 -> 2"
    other = replace(make_meta(seed=4), renderer="raster", expert={"type": "ExpertConfig", "x": 1})
    line = collection_mismatch(tmp_path, other, 3)
    assert line is not None and "\n" not in line
    assert "seed 0 -> 4" in line and 'renderer null -> "raster"' in line and "expert.x" in line
    assert collection_mismatch(tmp_path / "absent", make_meta(), 3) is None


def _flip_each_byte(path: Path, columns: tuple[str, ...]) -> Iterator[None]:
    """Rewrite ``path`` with one byte of the named columns' chunks flipped, each in turn."""
    import pyarrow.parquet as pq

    good = path.read_bytes()
    group = pq.ParquetFile(path).metadata.row_group(0)
    for j in range(group.num_columns):
        chunk = group.column(j)
        if chunk.path_in_schema.split(".")[0] not in columns:
            continue
        start = chunk.dictionary_page_offset or chunk.data_page_offset
        for at in range(start, start + chunk.total_compressed_size):
            bad = bytearray(good)
            bad[at] ^= 0x04
            path.write_bytes(bytes(bad))
            yield
    path.write_bytes(good)


def test_flipped_bits_in_scalar_columns_are_refused_naming_the_file(tmp_path: Path) -> None:
    """A bit flipped in an action, reward or cost column chunk that still decodes is refused
    by its checksum, by every reader of the columns; the damage is never read silently."""
    meta = init_dataset(tmp_path, make_meta())
    path = write_episode(tmp_path, make_episode(0), meta)
    clean = read_episodes(tmp_path, observations=False)[0]
    caught = 0
    for _ in _flip_each_byte(path, ("action", "reward", "cost_left")):
        for read in (
            lambda: read_episode(path, meta, observations=False),
            lambda: read_columns(tmp_path, ["reward", "cost_left"]),
        ):
            try:
                read()
            except DatasetError as e:
                message = str(e)
                assert "\n" not in message and message.startswith(f"{path}: ")
                caught += "do not match the checksum written with it (damaged)" in message
        with contextlib.suppress(DatasetError):  # read back: only unchanged values
            ep = read_episode(path, meta, observations=False)
            for name in ("actions", "rewards", "costs"):
                np.testing.assert_array_equal(getattr(ep, name), getattr(clean, name))
    assert caught > 0
    assert read_episodes(tmp_path)[0].rewards.tolist() == clean.rewards.tolist()


def test_files_without_column_checksums_are_read_as_before(tmp_path: Path) -> None:
    import pyarrow.parquet as pq

    from safe_bc.data.store import DIGEST_KEY

    meta = init_dataset(tmp_path, make_meta())
    path = write_episode(tmp_path, make_episode(0), meta)
    table = pq.read_table(path)
    kept = {k: v for k, v in table.schema.metadata.items() if k != DIGEST_KEY}
    table = table.set_column(
        table.column_names.index("reward"), "reward", pa.array(np.ones(12, np.float32))
    )
    pq.write_table(table.replace_schema_metadata(kept), path)
    assert read_episodes(tmp_path)[0].rewards.tolist() == [1.0] * 12
    assert read_columns(tmp_path, ["reward"])["reward"].tolist() == [1.0] * 12


def test_result_tables_carry_each_columns_unit(tmp_path) -> None:
    import pandas as pd

    from safe_bc.data.store import column_units, read_table, write_table_atomic
    from safe_bc.report import DISTANCE_UNIT

    frame = pd.DataFrame(
        {"method": ["a"], "reward": [1.0], "safety_mean": [2.0], "deferred_share": [0.1],
         "eval_seconds": [3.0], "episodes_beyond": [0]}
    )  # fmt: skip
    write_table_atomic(tmp_path / "t.parquet", frame, {"seed": 1, "git_revision": "abc"})
    units = column_units(tmp_path / "t.parquet")
    assert units["safety_mean"] == DISTANCE_UNIT and units["deferred_share"] == "fraction of 1"
    assert units["eval_seconds"] == "s" and units["episodes_beyond"] == "episodes"
    assert "method" not in units and units["reward"].startswith("return")
    table, meta = read_table(tmp_path / "t.parquet")
    assert table.equals(frame) and meta == {"seed": 1, "git_revision": "abc"}
