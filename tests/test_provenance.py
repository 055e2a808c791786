"""Provenance records the machine: CPU model, vendor, instruction set and torch's kernels, in
every result table."""

from __future__ import annotations

from pathlib import Path

import pandas as pd
import pytest
import torch

from safe_bc.data import provenance
from safe_bc.data.store import read_table_metadata, write_table_atomic

CPU_FIELDS = ("cpu_model", "cpu_vendor", "cpu_simd", "torch_version", "torch_cpu_capability")


@pytest.mark.parametrize(
    "metadata", [None, {"command": "x"}, {"provenance": provenance.provenance()}]
)
def test_a_written_table_records_the_cpu_and_torchs_kernels(tmp_path: Path, metadata) -> None:
    write_table_atomic(tmp_path / "t.parquet", pd.DataFrame({"x": [1.0]}), metadata)
    prov = read_table_metadata(tmp_path / "t.parquet")["provenance"]
    assert set(CPU_FIELDS) <= set(prov)
    assert prov["torch_version"] == torch.__version__
    assert prov["torch_cpu_capability"] == torch.backends.cpu.get_cpu_capability()
    assert prov["cpu_model"] and prov["cpu_vendor"]


def test_a_recorded_provenance_is_kept(tmp_path: Path) -> None:
    """A table rewritten from another run's rows keeps that run's provenance."""
    meta = {"provenance": {"git_revision": "abc", "cpu_model": "elsewhere"}}
    write_table_atomic(tmp_path / "t.parquet", pd.DataFrame({"x": [1.0]}), meta)
    assert read_table_metadata(tmp_path / "t.parquet")["provenance"]["cpu_model"] == "elsewhere"
    write_table_atomic(tmp_path / "u.parquet", pd.DataFrame({"x": [1.0]}),
                       provenance.run_metadata(rows=1))  # fmt: skip
    meta = read_table_metadata(tmp_path / "u.parquet")
    assert "provenance" not in meta and meta["torch_cpu_capability"]  # run_metadata: top level


def test_cpuinfo_parsing_for_x86_and_arm() -> None:
    amd = (
        "processor\t: 0\nvendor_id\t: AuthenticAMD\nmodel name\t: AMD EPYC 9B14 96-Core\n"
        "flags\t\t: fpu sse sse2 ssse3 sse4_1 sse4_2 avx f16c avx2 fma avx512f avx512bw\n\n"
        "processor\t: 1\nvendor_id\t: GenuineIntel\nflags\t\t: amx_tile\n"
    )
    assert provenance.parse_cpuinfo(amd) == {
        "cpu_model": "AMD EPYC 9B14 96-Core",
        "cpu_vendor": "AuthenticAMD",
        "cpu_simd": "sse4_2 avx avx2 fma f16c avx512f avx512bw",  # the first processor's only
    }
    arm = "processor\t: 0\nBogoMIPS\t: 50.00\nFeatures\t: fp asimd sve sve2\nCPU implementer\t: 0x41\nCPU part\t: 0xd4f\n"  # noqa: E501
    assert provenance.parse_cpuinfo(arm) == {
        "cpu_model": "part 0xd4f", "cpu_vendor": "ARM", "cpu_simd": "asimd sve sve2"
    }  # fmt: skip
    assert provenance.parse_cpuinfo("") == {"cpu_model": "", "cpu_vendor": "", "cpu_simd": ""}


def test_without_proc_cpuinfo_the_fields_fall_back(monkeypatch) -> None:
    """No /proc/cpuinfo (macOS, Windows): the platform's answer or "unknown", never an error."""
    real = Path.read_text

    def no_cpuinfo(self: Path, *a, **kw) -> str:
        if str(self) == "/proc/cpuinfo":
            raise FileNotFoundError(self)
        return real(self, *a, **kw)

    monkeypatch.setattr(Path, "read_text", no_cpuinfo)
    monkeypatch.setattr(provenance.platform, "system", lambda: "Darwin")
    monkeypatch.setattr(provenance.platform, "machine", lambda: "arm64")
    monkeypatch.setattr(provenance, "_sysctl", lambda name: {
        "machdep.cpu.brand_string": "Apple M2"}.get(name, ""))  # fmt: skip
    assert provenance._cpu() == {"cpu_model": "Apple M2", "cpu_vendor": "Apple",
                                 "cpu_simd": "asimd"}  # fmt: skip
    monkeypatch.setattr(provenance.platform, "system", lambda: "Windows")
    monkeypatch.setattr(provenance.platform, "processor", lambda: "")
    assert provenance._cpu() == {"cpu_model": "unknown", "cpu_vendor": "unknown",
                                 "cpu_simd": "unknown"}  # fmt: skip


def test_a_committed_unchanged_folder_is_a_published_result(tmp_path: Path) -> None:
    import subprocess

    from safe_bc.data.provenance import committed_unchanged

    def git(*args: str) -> None:
        subprocess.run(["git", *args], cwd=tmp_path, check=True, capture_output=True)

    study = tmp_path / "results" / "s"
    study.mkdir(parents=True)
    (study / "study.json").write_text("{}")
    assert not committed_unchanged(study)  # no git checkout
    git("init", "-q")
    assert not committed_unchanged(study)  # nothing tracked
    git("add", ".")
    git("-c", "user.name=t", "-c", "user.email=t@t", "commit", "-qm", "s")
    assert committed_unchanged(study)
    (study / "trials.parquet").write_text("new")  # an untracked new file: still the commit's
    assert committed_unchanged(study)
    (study / "study.json").write_text('{"a": 1}')  # a run went on here
    assert not committed_unchanged(study)
    git("checkout", "--", ".")
    (study / "study.json").unlink()
    assert not committed_unchanged(study)
    assert not committed_unchanged(tmp_path / "none")


def test_a_result_records_its_command_with_paths_relative_to_the_repository(monkeypatch) -> None:
    from safe_bc.data.provenance import RESULTS, run_metadata

    repo = RESULTS.parent
    argv = [str(repo / ".venv/bin/safe-bc"), "train", "--out", str(repo / "runs/a"), "--seed", "1"]
    monkeypatch.setattr("sys.argv", argv)
    assert run_metadata()["command"] == "safe-bc train --out runs/a --seed 1"
    monkeypatch.setattr(
        "sys.argv", [str(repo / "safe_bc/cli/commands.py"), "describe", "--out=/tmp/d"]
    )
    assert run_metadata()["command"] == "safe-bc describe --out=/tmp/d"  # elsewhere: as given
