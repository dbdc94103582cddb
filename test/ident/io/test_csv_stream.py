"""Streaming csv_import (issue 62 item 3): block boundaries, the bag streamed block by block equal to
the whole-file one, binary and NUL files refused fast, Ctrl-C ending cleanly with nothing written."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from aeropend_ident.cli.csv_import import main
from aeropend_ident.errors import CsvImportError
from aeropend_ident.io.bags import read_bag
from aeropend_ident.io.csv_import import CsvSpec, csv_to_bag, import_csv, stream_csv_to_bag
from aeropend_ident.io.csvread import source

SPEC = CsvSpec(name="t", time_col="t [s]", time_unit="s", input_col="PWM", input_kind="pwm",
               angle_col="angle [deg]", angle_unit="deg")
CSV_IMPORT = Path(sys.executable).parent / "csv_import"


def _log(path: Path, n: int, *, sep: str = ",", comma: bool = False, bom: bool = False,
         insert: dict[int, str] | None = None) -> Path:
    """A 490 Hz log of ``n`` rows; ``insert`` puts a raw line before data row k (0-based)."""
    lines = [f"t [s]{sep}PWM{sep}angle [deg]"]
    for k in range(n):
        if insert and k in insert:
            lines.append(insert[k])
        row = f"{k / 490:.6f}{sep}{(k * 7) % 256}{sep}{30 * np.sin(k / 50):.4f}"
        lines.append(row.replace(".", ",") if comma else row)
    path.write_bytes((b"\xef\xbb\xbf" if bom else b"") + ("\n".join(lines) + "\n").encode())
    return path


@pytest.fixture
def small_blocks(monkeypatch: pytest.MonkeyPatch) -> None:
    """Blocks of ~2 kB (about 80 rows) so a small log crosses many block boundaries."""
    monkeypatch.setattr(source, "BLOCK_BYTES", 2000)
    monkeypatch.setattr(source, "READ_BYTES", 700)


def test_blocks_give_the_whole_file_numbers(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    path = _log(tmp_path / "a.csv", 3000, insert={1000: "# a comment in the middle", 2000: ""})
    whole = import_csv(path, SPEC)
    monkeypatch.setattr(source, "BLOCK_BYTES", 2000)
    monkeypatch.setattr(source, "READ_BYTES", 700)
    parts = import_csv(path, SPEC)
    assert len(whole) == len(parts) == 3000
    assert np.array_equal(whole.t, parts.t) and np.array_equal(whole.duty, parts.duty)
    assert np.array_equal(whole.channels["theta"], parts.channels["theta"])
    assert parts.meta["comment_lines"] == 1 and parts.meta["blank_lines"] == 1
    assert parts.meta["csv_sha256"] == whole.meta["csv_sha256"]
    assert parts.duty[1] == pytest.approx(7 / 255) and parts.t[-1] == pytest.approx(2999 / 490)


def test_bad_row_in_a_later_block_named_by_line_and_counted(tmp_path: Path, small_blocks: None) -> None:
    # data row k is on line k + 2; the inserted lines shift the rows after them by one each
    path = _log(tmp_path / "b.csv", 2000, insert={1500: "3.1,12,abc", 1700: "3.5,12"})
    with pytest.raises(CsvImportError) as err:
        import_csv(path, SPEC)
    assert str(err.value) == (f"{path}:1502: column 'angle [deg]': 'abc' is not a number; 2 bad rows in all, "
                              "lines 1502, 1703; csv_import --drop-bad-rows drops them")
    with pytest.warns(UserWarning, match="dropped 2 bad rows of 2002"):
        rec = import_csv(path, SPEC, bad_rows="drop")
    assert len(rec) == 2000 and rec.meta["dropped_rows"]["count"] == 2


def test_time_not_increasing_across_a_block_boundary(tmp_path: Path, small_blocks: None) -> None:
    path = _log(tmp_path / "c.csv", 1000, insert={600: "0.5,1,1.0"})
    with pytest.raises(CsvImportError) as err:
        import_csv(path, SPEC)
    # the inserted row (line 602) goes back in time; the next row (line 603, 1.22449 s) is after it
    assert str(err.value) == (f"{path}:602: column 't [s]': time 0.5 s is not after the previous row's "
                              "1.22245 s (line 601); time must increase strictly (1 such row(s))")


def test_streamed_bag_equals_the_whole_file_bag(tmp_path: Path, small_blocks: None) -> None:
    """European Excel CSV (BOM, ';', decimal commas) across ~90 blocks: the streamed bag reads back
    as the bag csv_to_bag writes from the whole recording, stamps, wire shift and meta included."""
    path = _log(tmp_path / "eu.csv", 5000, sep=";", comma=True, bom=True)
    whole = csv_to_bag(path, tmp_path / "whole", SPEC)[1]
    res = stream_csv_to_bag(path, tmp_path / "stream", SPEC, stamp0_ns=0)
    a, b = read_bag(whole), read_bag(tmp_path / "stream")
    assert len(a) == len(b) == res.samples == 5000 and res.commands == 5000
    for x, y in ((a.t, b.t), (a.duty, b.duty), (a.channels["theta"], b.channels["theta"])):
        assert np.array_equal(x, y, equal_nan=True)
    assert b.duty[3] == pytest.approx(21 / 255) and b.t[-1] == pytest.approx(4999 / 490)
    assert b.meta["decimal"] == "," and b.meta["delimiter"] == ";"
    for key in ("rows", "n_gaps", "csv_sha256", "duty_clipped", "duration_s", "columns", "uniform"):
        assert a.meta[key] == b.meta[key], key
    for key in ("dt_median_s", "dt_min_s", "max_gap_s", "max_gap_at_s", "jitter_std_s"):  # block by block
        assert b.meta[key] == pytest.approx(a.meta[key], abs=1e-9), key


def test_failed_stream_leaves_no_bag_and_the_earlier_one_intact(tmp_path: Path, small_blocks: None) -> None:
    flags = ["--time-col", "t [s]", "--input-col", "PWM", "--input-kind", "pwm", "--angle-col", "angle [deg]",
             "--angle-unit", "deg"]
    bad = _log(tmp_path / "d.csv", 3000, insert={2500: "5.1,12,x"})  # a bad row in the 30th block
    out = tmp_path / "bag"
    assert main([str(bad), *flags, "-o", str(out)]) == 1
    assert not out.exists()
    assert main([str(_log(tmp_path / "good.csv", 700)), *flags, "-o", str(out)]) == 0
    assert main([str(bad), *flags, "-o", str(out), "--overwrite"]) == 1
    assert len(read_bag(out)) == 700  # the earlier bag, untouched
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bag", "d.csv", "good.csv"]  # no partial folder


@pytest.mark.parametrize("kind", ["nul_file", "sparse_2gb", "nul_after_header"])
def test_binary_files_refused_within_a_second(tmp_path: Path, kind: str,
                                              capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / f"{kind}.csv"
    if kind == "nul_file":
        path.write_bytes(b"\x00" * (1 << 20))
    elif kind == "sparse_2gb":
        with path.open("wb") as f:  # a 2 GB file of zeros taking no disk space
            f.truncate(2 << 30)
    else:
        path.write_bytes(b"t [s],PWM,angle [deg]\n0.0,1,2.0\n" + b"\x00" * 5000)
    out = tmp_path / "bag"
    t0 = time.perf_counter()
    code = main([str(path), "--preset", "aeroshield_ident", "-o", str(out)])
    elapsed = time.perf_counter() - t0
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 1 and elapsed < 1.0, elapsed
    assert len(err) == 1 and "a NUL byte" in err[0] and "binary file, not a CSV text" in err[0]
    assert err[0].startswith(f"csv_import: error: {path}:{3 if kind == 'nul_after_header' else 1}:")
    assert not out.exists()


@pytest.mark.slow
def test_ctrl_c_ends_cleanly_with_nothing_written(tmp_path: Path) -> None:
    path = tmp_path / "big.csv"
    with path.open("w") as f:  # 1.5 M rows, about 30 MB: several seconds to import
        f.write("t [s],PWM,angle [deg]\n")
        k = np.arange(1_500_000)
        np.savetxt(f, np.column_stack([k / 490, k % 256, np.sin(k / 50)]), fmt=["%.6f", "%d", "%.4f"],
                   delimiter=",")
    out = tmp_path / "bag"
    proc = subprocess.Popen([str(CSV_IMPORT), str(path), "--time-col", "t [s]", "--input-col", "PWM",
                             "--input-kind", "pwm", "--angle-col", "angle [deg]", "-o", str(out)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 30
    # the bag is written in a hidden sibling folder, moved to -o once complete
    while not list(tmp_path.glob(".bag.partial-*/bag/*.mcap")) and time.monotonic() < deadline \
            and proc.poll() is None:
        time.sleep(0.02)
    assert proc.poll() is None, "the import ended before it could be interrupted"
    os.kill(proc.pid, signal.SIGINT)
    stdout, stderr = proc.communicate(timeout=30)
    assert proc.returncode == 130
    # the one fault line of every command (aeropend_sim.output_folder.exits_cleanly_on_faults)
    assert stderr.strip().startswith("csv_import: error: interrupted (Ctrl-C)")
    assert f"{out} not written" in stderr and "\n" not in stderr.strip()
    assert "Traceback" not in stderr and stdout == ""
    assert sorted(p.name for p in tmp_path.iterdir()) == ["big.csv"]  # no bag, no partial folder


@pytest.mark.parametrize("encoding", ["utf-16", "latin-1"])
def test_other_encodings_streamed(tmp_path: Path, small_blocks: None, encoding: str) -> None:
    """UTF-16 (NUL bytes in every character: transcoded before the NUL check) and Latin-1 (a
    degree sign in the header) give the numbers of the UTF-8 file."""
    utf8 = _log(tmp_path / "a.csv", 1500)
    text = utf8.read_text(encoding="utf-8").replace("angle [deg]", "angle [°]")
    other = tmp_path / "b.csv"
    other.write_bytes(text.encode(encoding))
    spec = CsvSpec(name="t", time_col="t [s]", time_unit="s", input_col="PWM", input_kind="pwm",
                   angle_col="angle [°]", angle_unit="deg", encoding=encoding)
    a, b = import_csv(utf8, SPEC), import_csv(other, spec)
    assert len(b) == 1500 and np.array_equal(a.t, b.t)
    assert np.array_equal(a.channels["theta"], b.channels["theta"])
    assert b.meta["columns"]["theta"] == "angle [°]"
