"""safe_bc.data.atomic: whole new file or the old one, never a partial file or a stray temp file."""

from __future__ import annotations

import json
import stat

import pytest

from safe_bc.data.atomic import (
    atomic_write,
    write_bytes_atomic,
    write_json_atomic,
    write_text_atomic,
)


def test_error_mid_write_keeps_the_old_file_and_no_temp_file(tmp_path):
    target = tmp_path / "table.bin"
    target.write_bytes(b"old contents")
    with pytest.raises(RuntimeError, match="disk on fire"), atomic_write(target) as f:
        f.write(b"new cont")
        raise RuntimeError("disk on fire")
    assert target.read_bytes() == b"old contents"
    assert [p.name for p in tmp_path.iterdir()] == ["table.bin"]


def test_error_before_first_write_leaves_no_file(tmp_path):
    target = tmp_path / "sub" / "new.json"
    with pytest.raises(TypeError):
        write_json_atomic(target, {"x": object()})
    assert list(tmp_path.rglob("*")) == []


def test_writes_replace_and_create_directories(tmp_path):
    target = tmp_path / "a" / "b" / "x.txt"
    write_text_atomic(target, "one")
    write_text_atomic(target, "two")
    assert target.read_text() == "two"
    write_bytes_atomic(target, b"\x00\x01")
    assert target.read_bytes() == b"\x00\x01"
    assert stat.S_IMODE(target.stat().st_mode) == 0o644
    assert [p.name for p in target.parent.iterdir()] == ["x.txt"]


def test_json_matches_the_old_format(tmp_path):
    obj = {"b": [1, 2.5], "a": None, "nan": float("nan")}
    target = tmp_path / "x.json"
    write_json_atomic(target, obj)
    assert target.read_text() == json.dumps(obj, indent=2) + "\n"
    with pytest.raises(ValueError):
        write_json_atomic(target, obj, allow_nan=False)
    assert target.read_text() == json.dumps(obj, indent=2) + "\n"


def test_rejects_other_modes(tmp_path):
    with pytest.raises(ValueError, match="mode"), atomic_write(tmp_path / "x", "a"):
        pass
    assert list(tmp_path.iterdir()) == []


def test_parquet_tables_and_figures_go_through_it(tmp_path):
    import matplotlib.pyplot as plt
    import pandas as pd

    from safe_bc.data.store import read_table, write_table_atomic
    from safe_bc.plots import save_figure

    frame = pd.DataFrame({"x": [1, 2, 3]})
    write_table_atomic(tmp_path / "t.parquet", frame, {"k": 1})
    back, meta = read_table(tmp_path / "t.parquet")
    assert back.equals(frame) and meta["k"] == 1 and "provenance" in meta

    fig, ax = plt.subplots()
    ax.plot([0, 1])
    save_figure(fig, tmp_path / "f.png")
    assert (tmp_path / "f.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["f.png", "t.parquet"]
