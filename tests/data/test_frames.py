"""Decoded frames on disk: the frame file, and the store's streamed datasets built on it."""

from __future__ import annotations

import os
import pickle
from pathlib import Path

import numpy as np
import pytest

from safe_bc.data.frames import FrameFile, FrameFileError, checksum_path, write_frame_file
from safe_bc.data.store import (
    FRAME_CACHE_DIR,
    DatasetError,
    init_dataset,
    load_demonstrations,
    write_episode,
)
from tests.data.test_store import make_episode, make_meta

SHAPE = (4, 5, 3)


def _frames(n: int = 11, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 256, (n, *SHAPE), dtype=np.uint8)


def _file(tmp_path: Path, frames: np.ndarray, chunk: int = 4) -> FrameFile:
    path = tmp_path / "f.npy"
    write_frame_file(
        path, frames.shape, (frames[i : i + chunk] for i in range(0, len(frames), chunk))
    )
    return FrameFile(path, frames.shape)


def test_indexing_gives_the_arrays_of_the_in_memory_frames(tmp_path: Path) -> None:
    frames = _frames()
    f = _file(tmp_path, frames)
    assert len(f) == 11 and f.shape == frames.shape and f.ndim == 4 and f.dtype == np.uint8
    for key in (
        np.array([3, 1, 1, 10, 0, 4, 5, 6]),  # unsorted, repeated, runs of consecutive rows
        np.array([-1, 2]),
        np.array([], np.int64),
        frames[:, 0, 0, 0] > 128,
        slice(2, 9, 3),
        7,
    ):
        got, want = f[key], frames[key]
        assert got.dtype == want.dtype and got.shape == want.shape
        np.testing.assert_array_equal(got, want)
        assert got.flags.c_contiguous
    np.testing.assert_array_equal(np.asarray(f), frames)  # and np.load reads the file too
    np.testing.assert_array_equal(np.load(f.path), frames)
    with pytest.raises(IndexError):
        f[np.array([11])]
    again = pickle.loads(pickle.dumps(f))
    np.testing.assert_array_equal(again[np.array([9, 2])], frames[[9, 2]])


def test_truncated_or_wrong_file_is_detected(tmp_path: Path) -> None:
    frames = _frames()
    f = _file(tmp_path, frames)
    with pytest.raises(FrameFileError, match="expected uint8"):
        FrameFile(f.path, (12, *SHAPE))
    with open(f.path, "r+b") as fh:
        fh.truncate(os.path.getsize(f.path) - 1)
    with pytest.raises(FrameFileError, match="truncated"):
        FrameFile(f.path, frames.shape)
    (tmp_path / "g.npy").write_bytes(b"not numpy")
    with pytest.raises(FrameFileError, match=r"not a \.npy"):
        FrameFile(tmp_path / "g.npy", frames.shape)


def test_altered_frames_fail_the_checksum(tmp_path: Path) -> None:
    frames = _frames()
    f = _file(tmp_path, frames)
    f.verify()
    with open(f.path, "r+b") as fh:  # one frame zeroed: same size, same header
        fh.seek(f._offset + 3 * int(np.prod(SHAPE)))
        fh.write(bytes(int(np.prod(SHAPE))))
    with pytest.raises(FrameFileError, match=r"f\.npy: its frames do not match the checksum"):
        FrameFile(f.path, frames.shape).verify()
    checksum_path(f.path).unlink()
    with pytest.raises(FrameFileError, match=r"f\.npy: no checksum"):
        FrameFile(f.path, frames.shape).verify()


def test_write_is_atomic(tmp_path: Path) -> None:
    frames = _frames()
    f = _file(tmp_path, frames)

    def failing():
        yield frames[:4]
        raise RuntimeError("interrupted")

    with pytest.raises(RuntimeError):
        write_frame_file(f.path, frames.shape, failing())
    with pytest.raises(ValueError, match="4 frames written"):  # too few rows: refused too
        write_frame_file(f.path, frames.shape, iter([frames[:4]]))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["f.npy", "f.sha256"]  # the old, whole
    f.verify()
    np.testing.assert_array_equal(FrameFile(f.path, frames.shape)[np.arange(11)], frames)


# ------------------------------------------------------------ the store's streamed datasets
def _dataset(root: Path, lengths: tuple[int, ...] = (5, 7)) -> list:
    meta = init_dataset(root, make_meta("png"))
    eps = [make_episode(i, n=n) for i, n in enumerate(lengths)]
    for ep in eps:
        write_episode(root, ep, meta)
    return eps


def _cache_files(root: Path) -> list[Path]:
    return sorted((root / FRAME_CACHE_DIR).glob("*"))


def test_stream_gives_the_memory_arrays(tmp_path: Path) -> None:
    _dataset(tmp_path)
    mem = load_demonstrations(tmp_path, "memory")
    assert not (tmp_path / FRAME_CACHE_DIR).exists()  # memory mode writes nothing
    stream = load_demonstrations(tmp_path, "stream")
    assert isinstance(stream.observations, FrameFile)
    rows = np.array([11, 0, 5, 4, 4])
    np.testing.assert_array_equal(stream.observations[rows], mem.observations[rows])
    for name in ("actions", "costs", "safety", "episode_ids", "steps", "seeds", "warmup"):
        np.testing.assert_array_equal(getattr(stream, name), getattr(mem, name))


def test_frame_cache_is_written_once_and_rebuilt_when_the_dataset_changes(
    tmp_path: Path,
) -> None:
    eps = _dataset(tmp_path)
    first = load_demonstrations(tmp_path, "stream").observations.path
    stamp = first.stat().st_mtime_ns
    assert load_demonstrations(tmp_path, "stream").observations.path == first
    assert first.stat().st_mtime_ns == stamp
    assert _cache_files(tmp_path) == [first, checksum_path(first)]
    # an episode rewritten with other frames: a new file with the new frames, the old one gone
    changed = make_episode(1, n=7, seed=0)
    changed.observations[:] = 255 - eps[1].observations
    write_episode(tmp_path, changed, make_meta("png"))
    demos = load_demonstrations(tmp_path, "stream")
    assert demos.observations.path != first
    assert _cache_files(tmp_path) == [
        demos.observations.path,
        checksum_path(demos.observations.path),
    ]
    np.testing.assert_array_equal(demos.observations[np.arange(5, 12)], changed.observations)
    # an episode added
    write_episode(tmp_path, make_episode(2, n=3), make_meta("png"))
    assert len(load_demonstrations(tmp_path, "stream").observations) == 15


def test_truncated_frame_cache_is_written_again(tmp_path: Path) -> None:
    _dataset(tmp_path)
    path = load_demonstrations(tmp_path, "stream").observations.path
    whole = path.read_bytes()
    path.write_bytes(whole[: len(whole) // 2])
    demos = load_demonstrations(tmp_path, "stream")
    assert demos.observations.path == path and path.read_bytes() == whole


def test_a_read_only_dataset_caches_its_frames_in_the_users_cache(
    tmp_path: Path, monkeypatch
) -> None:
    from safe_bc.data import store

    data, cache = tmp_path / "data", tmp_path / "cache"
    data.mkdir()
    _dataset(data)
    monkeypatch.setenv("SAFE_BC_CACHE", str(cache))
    real = store.write_frame_file

    def read_only_data(path, *args, **kwargs):
        if Path(path).is_relative_to(data):
            raise PermissionError("read-only file system")
        return real(path, *args, **kwargs)

    monkeypatch.setattr("safe_bc.data.store.write_frame_file", read_only_data)
    demos = load_demonstrations(data, "stream")
    assert demos.observations.path.parent == cache / FRAME_CACHE_DIR
    np.testing.assert_array_equal(
        demos.observations[np.arange(12)], load_demonstrations(data, "memory").observations
    )
    stamp = demos.observations.path.stat().st_mtime_ns  # found there again, not rewritten
    assert load_demonstrations(data, "stream").observations.path.stat().st_mtime_ns == stamp

    def refuse(*args, **kwargs):
        raise PermissionError("read-only file system")

    monkeypatch.setattr("safe_bc.data.store.write_frame_file", refuse)
    monkeypatch.setenv("SAFE_BC_CACHE", str(tmp_path / "other"))
    with pytest.raises(DatasetError, match="frames='memory'") as e:
        load_demonstrations(data, "stream")
    assert str(data) in str(e.value) and str(tmp_path / "other") in str(e.value)


def test_zeroed_frames_in_the_cache_are_rebuilt_saying_so(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    eps = _dataset(tmp_path)
    path = load_demonstrations(tmp_path, "stream").observations.path
    whole = path.read_bytes()
    capsys.readouterr()
    path.write_bytes(whole[: len(whole) - 500] + bytes(500))  # the last frame's tail zeroed
    demos = load_demonstrations(tmp_path, "stream")
    assert demos.observations.path == path and path.read_bytes() == whole
    np.testing.assert_array_equal(demos.observations[np.arange(5, 12)], eps[1].observations)
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and err[0].startswith(f"{path}: its frames do not match the checksum")
    load_demonstrations(tmp_path, "stream")  # whole again: nothing said
    assert capsys.readouterr().err == ""
    # a cache without its checksum (written before it was recorded) is written again quietly
    checksum_path(path).unlink()
    path.write_bytes(whole[: len(whole) - 500] + bytes(500))
    load_demonstrations(tmp_path, "stream")
    assert path.read_bytes() == whole and checksum_path(path).is_file()
    # damaged, and it cannot be written again: one line naming the file
    path.write_bytes(whole[: len(whole) - 500] + bytes(500))

    def refuse(*args, **kwargs):
        raise PermissionError("read-only file system")

    monkeypatch.setattr("safe_bc.data.store.write_frame_file", refuse)
    monkeypatch.setenv("SAFE_BC_CACHE", str(tmp_path / "cache"))
    with pytest.raises(DatasetError) as info:
        load_demonstrations(tmp_path, "stream")
    assert "\n" not in str(info.value) and f"{path}: read-only" in str(info.value)
