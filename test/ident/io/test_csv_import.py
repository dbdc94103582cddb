"""CSV import: real third-party logs (numbers from shared/data/real/README.md) and malformed files."""

from __future__ import annotations

import gzip
import math
import re
import warnings
from pathlib import Path

import numpy as np
import pytest

from aeropend_ident.cli.csv_import import main
from aeropend_ident.errors import CsvImportError, CsvRowWarning
from aeropend_ident.io.bags import read_bag
from aeropend_ident.io.csv_import import PRESETS, CsvSpec, find_preset, import_csv, import_csv_runs

REAL = Path(__file__).resolve().parents[4] / "shared" / "data" / "real"
HOJA3 = REAL / "jahoyosr__Aeropendulum" / "sheet_Hoja3_pwm_steps_openloop.csv"
AEROSHIELD = REAL / "gergelytakacs__AutomationShield" / "AeroShield" / "Identification_Data.csv"
ESCALONES = REAL / "jahoyosr__Aeropendulum"
ETCHE = REAL / "BA-Etchepareborda__adaptive-control-aeropendulum"
MATHEUS = REAL / "matheusbucater__aeropendulo"

real_data = pytest.mark.skipif(not REAL.is_dir(), reason=f"real recordings not found at {REAL}")


def _segments(duty: np.ndarray) -> list[np.ndarray]:
    """Index arrays of constant-duty segments."""
    return np.split(np.arange(duty.size), np.flatnonzero(np.diff(duty)) + 1)


# ------------------------------------------------------------------ real files


@real_data
@pytest.mark.real_data
def test_hoja3_staircase() -> None:
    rec = import_csv(HOJA3, "jahoyosr_hoja3")
    assert len(rec) == 15555
    assert rec.dt == pytest.approx(1 / 70, rel=1e-5)
    assert rec.meta["rate_hz"] == pytest.approx(70.0, rel=1e-5)
    assert rec.t[-1] == pytest.approx(222.2143746, abs=1e-9)
    # one dropped sample (a 2-period gap) is kept and reported, not resampled
    assert rec.meta["n_gaps"] == 1 and rec.meta["max_gap_s"] == pytest.approx(2 / 70, rel=1e-5)
    # PWM steps by 2 every 10 s from 180 to 224
    segs = _segments(rec.duty)
    pwm = [rec.duty[s[0]] * 255 for s in segs]
    assert np.allclose(pwm, np.arange(180, 225, 2))
    assert rec.duty.min() == 180 / 255 and rec.duty.max() == 224 / 255
    assert [len(s) for s in segs[:-1]] == [700] * 22  # 10 s at 70 Hz
    # angle in rad, README: range -37.4 deg (lower stop) .. +36.1 deg (upper stop)
    deg = np.degrees(rec.channels["theta"])
    assert deg.min() == pytest.approx(-37.49, abs=1e-9) and deg.max() == pytest.approx(36.26, abs=1e-9)
    # README steady angles (PWM -> deg); mean over the last 2 s of each step
    steady = {round(rec.duty[s[0]] * 255): deg[s[-140:]].mean() for s in segs}
    for p in (180, 186, 192):
        assert steady[p] == pytest.approx(-37.4, abs=0.3)
    for p, readme in ((194, -35.1), (200, -31.5), (210, -24.9), (214, -21.4), (222, 36.1)):
        assert steady[p] == pytest.approx(readme, abs=0.3), p
    assert rec.meta["licence"].startswith("none stated")
    assert "735dd93e" in rec.meta["provenance"]


@real_data
@pytest.mark.real_data
def test_aeroshield_identification() -> None:
    rec = import_csv(AEROSHIELD, "aeroshield_ident")
    assert len(rec) == 4812
    assert rec.dt == pytest.approx(0.015, rel=1e-12)
    assert rec.meta["uniform"] and rec.meta["n_gaps"] == 0
    assert rec.t[-1] == pytest.approx(4811 * 0.015, rel=1e-12)
    # README: u takes 15 levels between 0 and 1.91 V -> 15 duty levels; firmware:
    # PWM = floor(255 u^2 / 3.7^2), so the top level 1.90572 V gives floor(67.65) = 67 counts
    levels = np.unique(rec.duty)
    assert levels.size == 15
    assert levels[0] == 0.0 and levels[-1] == 67 / 255
    assert np.allclose(levels * 255, np.round(levels * 255))  # integer PWM counts
    th = rec.channels["theta"]
    assert th.min() == 0.0 and th.max() == pytest.approx(1.06612, abs=1e-12)
    assert "CC BY-NC-ND 4.0" in rec.meta["licence"]
    assert "3.7" in rec.meta["input_note"]


@real_data
@pytest.mark.real_data
def test_etchepareborda_steps() -> None:
    rec = import_csv(ETCHE / "openloop_steps_0_100_180.csv", "etchepareborda_openloop")
    assert len(rec) == 8708
    assert rec.dt == pytest.approx(0.02, rel=1e-9) and rec.meta["n_gaps"] == 0
    assert rec.t[-1] == pytest.approx(174.14, abs=1e-9)
    assert set(np.unique(rec.duty)) == {0.0, 100 / 255, 180 / 255}
    segs = _segments(rec.duty)
    assert [round(rec.duty[s[0]] * 255) for s in segs[:6]] == [0, 100, 180, 0, 100, 180]
    assert [len(s) * 0.02 for s in segs[:3]] == pytest.approx([4.0, 4.0, 8.0])
    # README steady theta: PWM 100 -> 0.39-0.41 rad, PWM 180 -> 0.68-0.79 rad. Mean of the last second of
    # each step: the first six PWM-100 steps match; later repeats drift up (0.44-0.47 rad, the rig warms up
    # or the MPU6050 filter drifts), which the README's range does not mention; imported as is.
    steady: dict[int, list[float]] = {100: [], 180: []}
    for s in segs:
        level = round(rec.duty[s[0]] * 255)
        if level in steady and len(s) >= 200:
            steady[level].append(float(rec.channels["theta"][s[-50:]].mean()))
    assert len(steady[100]) == 11 and len(steady[180]) == 11
    assert all(0.39 <= v <= 0.42 for v in steady[100][:6])
    assert max(steady[100]) == pytest.approx(0.47, abs=0.005)
    assert 0.68 <= float(np.median(steady[180])) <= 0.79
    other = import_csv(ETCHE / "openloop_steps_0_100_130.csv", "etchepareborda_openloop")
    assert set(np.unique(other.duty)) == {0.0, 100 / 255, 130 / 255}
    assert other.t[-1] == pytest.approx(116.46, abs=1e-9)


@real_data
@pytest.mark.real_data
def test_matheusbucater_sawtooth_and_step() -> None:
    saw = import_csv(MATHEUS / "aeropendulum.csv", "matheusbucater_sawtooth")
    assert saw.meta["delimiter"] == ";"
    assert len(saw) == 799
    assert saw.dt == pytest.approx(0.016)  # FreeRTOS tick 16-17 ms
    dts = set(np.round(np.diff(saw.t) * 1e3).astype(int).tolist())
    assert dts == {16, 17, 32}
    assert saw.t[-1] == pytest.approx(12.887, abs=1e-12)
    assert saw.duty.min() == 0.0 and saw.duty.max() == 149 / 255  # sawtooth 0..149
    deg = np.degrees(saw.channels["theta"])
    assert np.allclose(deg, np.round(deg))  # 1-degree potentiometer resolution

    step = import_csv(MATHEUS / "aeropendulum_step.csv", "matheusbucater_step")
    assert len(step) == 799
    assert np.all(step.duty == 80 / 255)  # no PWM column: the preset's constant
    assert step.t[-1] == pytest.approx(12.870, abs=1e-12)
    final = np.degrees(step.channels["theta"][step.t > step.t[-1] - 2.0]).mean()
    assert final == pytest.approx(60.6, abs=1.0)  # README: settles at about 60.6 deg
    assert "held at" in step.meta["input_note"]


@real_data
@pytest.mark.real_data
def test_jahoyosr_escalones_no_time_column() -> None:
    """datosEscalones: no time column (70 Hz assumed), README: S-T PWM 210..229 by 1, A-B 150..240 by 5."""
    st = import_csv(ESCALONES / "sheet_datosEscalones_colsST_pwm_steps_no_time.csv", "jahoyosr_escalones")
    assert len(st) == 23999 and st.dt == pytest.approx(1 / 70, rel=1e-9)
    assert st.meta["n_gaps"] == 0
    pwm = [round(st.duty[s[0]] * 255) for s in _segments(st.duty)]
    assert pwm == list(range(210, 230))
    assert [len(s) for s in _segments(st.duty)[1:-1]] == [1200] * 18
    ab = import_csv(ESCALONES / "sheet_datosEscalones_colsAB_pwm_steps_no_time.csv", "jahoyosr_escalones")
    assert len(ab) == 22478
    assert sorted({round(d * 255) for d in ab.duty}) == list(range(150, 241, 5))
    deg = np.degrees(ab.channels["theta"])
    assert deg[0] == pytest.approx(-37.68, abs=1e-9) and deg.max() == pytest.approx(36.35, abs=1e-9)
    for sheet in ("colsAB", "colsST"):
        name = f"sheet_datosEscalones_{sheet}_pwm_steps_no_time.csv"
        assert find_preset(ESCALONES / name) == "jahoyosr_escalones"


@real_data
@pytest.mark.real_data
def test_presets_found_by_file_name() -> None:
    assert find_preset(HOJA3) == "jahoyosr_hoja3"
    assert find_preset(AEROSHIELD) == "aeroshield_ident"
    assert find_preset(ETCHE / "openloop_random_binary_80_120.csv") == "etchepareborda_openloop"
    assert find_preset(MATHEUS / "aeropendulum_step.csv") == "matheusbucater_step"
    assert find_preset("unrelated.csv") is None
    for name, spec in PRESETS.items():
        assert spec.name == name
        assert spec.meta["licence"] and spec.meta["provenance"].startswith("https://github.com/")


def test_presets_are_yaml_package_data() -> None:
    """Every preset is one YAML file in ``aeropend_ident/io/presets`` and loads to a valid spec."""
    from importlib import resources

    from aeropend_ident.io.csv_import import load_presets

    files = sorted(e.name for e in (resources.files("aeropend_ident.io") / "presets").iterdir()
                   if e.name.endswith(".yaml"))
    assert files == sorted(f"{name}.yaml" for name in PRESETS)
    assert load_presets() == PRESETS
    for name, spec in PRESETS.items():
        spec.check()
        assert spec.name == name and spec.meta["files"] and spec.meta["licence"]
        assert all(isinstance(col, str) and isinstance(scale, float) for col, scale in spec.channels.values())
    assert PRESETS["yangzhu_pitch_step"].channels["omega_rotor"] == ("tach_pitch_motor", 2 * math.pi / 2048)


@real_data
@pytest.mark.real_data
def test_cli_writes_bag_that_reads_back(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "hoja3_bag"
    assert main([str(HOJA3), "-o", str(out), "--preset", "auto", "--storage", "sqlite3"]) == 0
    text = capsys.readouterr().out
    assert "15555 samples" in text and "70.00 Hz" in text and "['theta']" in text
    rec = import_csv(HOJA3, "jahoyosr_hoja3")
    back = read_bag(out)
    assert np.array_equal(back.duty, rec.duty)
    assert np.array_equal(back.channels["theta"], rec.channels["theta"])
    assert sorted(back.channels) == ["theta"]
    assert np.max(np.abs(back.t - rec.t)) <= 0.5e-9
    assert back.meta["licence"] == rec.meta["licence"] and back.meta["preset"] == "jahoyosr_hoja3"


# ------------------------------------------------------------------ synthetic files


def _write(path: Path, text: str) -> Path:
    path.write_text(text, encoding="utf-8")
    return path


def _rows(n: int, bad_line: int | None = None, bad: str = "abc") -> str:
    lines = ["t [s],PWM [0-255],angle [deg]"]
    for k in range(n):
        angle = f"{-10 + 0.5 * k:.2f}"
        lines.append(f"{k * 0.02:.2f},{100 + k % 7},{angle}")
    if bad_line is not None:
        fields = lines[bad_line - 1].split(",")
        fields[2] = bad
        lines[bad_line - 1] = ",".join(fields)
    return "\n".join(lines) + "\n"


SPEC = CsvSpec(time_col="t [s]", input_col="PWM [0-255]", input_kind="pwm", angle_col="angle [deg]",
               angle_unit="deg")


def test_not_a_number_names_file_line_column(tmp_path: Path) -> None:
    path = _write(tmp_path / "data.csv", _rows(80, bad_line=57))
    with pytest.raises(CsvImportError) as err:
        import_csv(path, SPEC)
    expected = f"{path}:57: column 'angle [deg]': 'abc' is not a number; csv_import --drop-bad-rows drops it"
    assert str(err.value) == expected


def test_empty_cell_and_short_line(tmp_path: Path) -> None:
    path = _write(tmp_path / "empty.csv", _rows(20, bad_line=9, bad=""))
    with pytest.raises(CsvImportError, match=r"empty\.csv:9: column 'angle \[deg\]': '' is empty"):
        import_csv(path, SPEC)
    text = _rows(20).splitlines()
    text[13] = "0.24,101"  # line 14 lacks the angle field
    path = _write(tmp_path / "short.csv", "\n".join(text) + "\n")
    with pytest.raises(CsvImportError, match=r"short\.csv:14: row has 2 fields, expected 3; "):
        import_csv(path, SPEC)


def test_nan_cell_in_required_column(tmp_path: Path) -> None:
    path = _write(tmp_path / "nan.csv", _rows(20, bad_line=5, bad="nan"))
    expected = r"nan\.csv:5: column 'angle \[deg\]': 'nan' is not a finite"
    with pytest.raises(CsvImportError, match=expected):
        import_csv(path, SPEC)


def test_time_must_increase(tmp_path: Path) -> None:
    text = _rows(30).splitlines()
    text[20] = "0.36,100,1.0"  # line 21: t = 0.36 after 0.38 on line 20
    path = _write(tmp_path / "back.csv", "\n".join(text) + "\n")
    expected = r"back\.csv:21: column 't \[s\]': time 0\.36 s is not after"
    with pytest.raises(CsvImportError, match=expected):
        import_csv(path, SPEC)


def test_missing_column_lists_header(tmp_path: Path) -> None:
    path = _write(tmp_path / "cols.csv", _rows(5))
    spec = CsvSpec(time_col="time", input_col="PWM [0-255]", input_kind="pwm", angle_col="angle [deg]")
    with pytest.raises(CsvImportError, match=r"cols\.csv:1: no time column 'time'; header has"):
        import_csv(path, spec)
    with pytest.raises(CsvImportError, match="column index 7 out of range; the file has 3 column"):
        import_csv(path, CsvSpec(time_col=0, input_col=1, input_kind="pwm", angle_col=7))


def test_not_utf8_and_missing_file(tmp_path: Path) -> None:
    path = tmp_path / "latin.csv"
    path.write_bytes(b"t,u,angle\n0,1,2\n0.1,1,\xb0\n")
    with pytest.raises(CsvImportError, match=r"latin\.csv:3: bytes are not valid utf-8"):
        import_csv(path, CsvSpec(time_col="t", input_col="u", angle_col="angle"))
    with pytest.raises(CsvImportError, match="cannot read file"):
        import_csv(tmp_path / "absent.csv", SPEC)


def test_semicolon_decimal_comma_comments_gz(tmp_path: Path) -> None:
    body = (
        "# logged by the lab rig\n"
        "# 3 columns\n"
        "Zeit [ms];Tastgrad [%];Winkel [deg];Strom [mA]\n"
        "0;10,5;-1,25;100\n"
        "\n"
        "20;12,5;-0,75;\n"
        "# pause\n"
        "45;150;0,5;120,5\n"
        "60;-3;1,0;130\n"
    )
    spec = CsvSpec(time_col="Zeit", time_unit="ms", input_col="Tastgrad", input_kind="percent",
                   angle_col="Winkel", angle_unit="deg", angle_zero=-1.25, angle_sign=-1.0,
                   channels={"i_a": ("Strom [mA]", 1e-3)})
    plain = _write(tmp_path / "comma.csv", body)
    packed = tmp_path / "comma.csv.gz"
    packed.write_bytes(gzip.compress(body.encode()))
    for path in (plain, packed):
        with pytest.warns(UserWarning, match="2 actuator value"):
            rec = import_csv(path, spec)
        assert rec.meta["delimiter"] == ";" and rec.meta["decimal"] == ","
        assert rec.meta["comment_lines"] == 3 and rec.meta["blank_lines"] == 1
        assert rec.t.tolist() == pytest.approx([0.0, 0.02, 0.045, 0.06])
        assert rec.duty.tolist() == pytest.approx([0.105, 0.125, 1.0, 0.0])  # 150 % and -3 % clipped
        assert rec.meta["duty_clipped"] == {"below_0": 1, "above_1": 1}
        expected = [-(a + 1.25) * math.pi / 180 for a in (-1.25, -0.75, 0.5, 1.0)]
        assert rec.channels["theta"].tolist() == pytest.approx(expected, abs=1e-15)
        i_a = rec.channels["i_a"]
        assert i_a[0] == pytest.approx(0.1) and math.isnan(i_a[1]) and i_a[2] == pytest.approx(0.1205)
        # irregular time kept and reported
        assert rec.meta["dt_median_s"] == pytest.approx(0.02)
        assert rec.meta["max_gap_s"] == pytest.approx(0.025)


def test_no_time_column_uses_rate(tmp_path: Path) -> None:
    body = "".join(f"{0.3 + 0.01 * (k % 3)}\t{0.001 * k}\n" for k in range(250))
    path = _write(tmp_path / "notime.tsv", body)
    spec = CsvSpec(time_col=None, rate_hz=490.0, input_col=0, input_kind="duty", angle_col=1)
    rec = import_csv(path, spec)
    assert rec.meta["header"] is None and rec.meta["delimiter"] == "\t"
    assert len(rec) == 250
    assert rec.t[-1] == pytest.approx(249 / 490)
    assert rec.meta["uniform"] and rec.meta["rate_hz"] == pytest.approx(490.0)
    assert rec.duty[:3].tolist() == [0.3, 0.31, 0.32]
    assert rec.channels["theta"][-1] == pytest.approx(0.249)
    with pytest.raises(CsvImportError, match="rate_hz = None; a positive sample rate"):
        import_csv(path, CsvSpec(input_col=0, angle_col=1))


def test_runs_split_at_the_label_column(tmp_path: Path) -> None:
    """Three runs of 4, 1 and 5 samples stored one after the other; label 7 comes back later."""
    labels = [7] * 4 + [2] + [7] * 5
    body = "run,PWM [0-255],angle [deg]\n" + "".join(
        f"{lab},{100 + k},{0.5 * k}\n" for k, lab in enumerate(labels)
    )
    path = _write(tmp_path / "runs.csv", body)
    spec = CsvSpec(time_col=None, rate_hz=10.0, input_col="PWM [0-255]", input_kind="pwm",
                   angle_col="angle [deg]", angle_unit="deg")
    runs = import_csv_runs(path, spec, "run")
    assert [len(r) for r in runs] == [4, 5]  # the 1-sample run is below min_samples = 2
    assert runs[1].t[0] == 0.0 and runs[1].duty[0] == pytest.approx(105 / 255)  # re-based
    assert runs[1].channels["theta"][0] == pytest.approx(math.radians(2.5))
    assert [len(r) for r in import_csv_runs(path, spec, 0, min_samples=5)] == [5]  # label by index
    with pytest.raises(ValueError, match="min_samples 1: expected >= 2"):
        import_csv_runs(path, spec, "run", min_samples=1)
    with pytest.raises(CsvImportError, match="no run label column 'piece'"):
        import_csv_runs(path, spec, "piece")
    bad = _write(tmp_path / "bad.csv", body.replace("\n2,", "\nx,"))
    with pytest.raises(CsvImportError, match=":6: column 'run': 'x' is not a number"):
        import_csv_runs(bad, spec, "run")


def test_voltage_input_linear_and_rms(tmp_path: Path) -> None:
    path = _write(tmp_path / "volt.csv", "t,u [V],y\n0,0,0\n0.01,6,0.1\n0.02,12,0.2\n0.03,13,0.25\n")
    lin = CsvSpec(time_col="t", input_col="u", input_kind="voltage", supply_voltage=12.0, angle_col="y")
    with pytest.warns(UserWarning, match="1 actuator value"):
        rec = import_csv(path, lin)
    assert rec.duty.tolist() == [0.0, 0.5, 1.0, 1.0]
    assert rec.meta["duty_clipped"] == {"below_0": 0, "above_1": 1}
    rms = CsvSpec(time_col="t", input_col="u", input_kind="voltage", supply_voltage=12.0, voltage_law="rms",
                  quantize_counts=255, angle_col="y")
    with pytest.warns(UserWarning):
        rec = import_csv(path, rms)
    assert rec.duty.tolist() == [0.0, 63 / 255, 1.0, 1.0]  # floor(255 * 0.25) = 63
    with pytest.raises(CsvImportError, match=r"input_kind .voltage. needs input_span \[V\]"):
        import_csv(path, CsvSpec(time_col="t", input_col="u", input_kind="voltage", angle_col="y"))


def test_cli_custom_columns(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = _write(tmp_path / "log.csv", _rows(100))
    out = tmp_path / "bag"
    code = main([str(path), "-o", str(out), "--time-col", "t [s]", "--angle-col", "angle",
                 "--angle-unit", "deg", "--pwm-col", "PWM", "--pwm-full-scale", "255"])
    assert code == 0
    assert "100 samples over 1.980 s" in capsys.readouterr().out
    back = read_bag(out)
    assert back.duty[0] == 100 / 255 and back.duty[6] == 106 / 255
    assert back.channels["theta"][2] == pytest.approx(math.radians(-9.0))
    bad = _write(tmp_path / "bad.csv", _rows(10, bad_line=4, bad="x1"))
    assert main([str(bad), "--time-col", "0", "--angle-col", "2", "--pwm-col", "1"]) == 1
    assert "bad.csv:4: column 'angle [deg]': 'x1' is not a number" in capsys.readouterr().err


def test_cli_start_time_gives_the_bag_a_real_clock(tmp_path: Path) -> None:
    """Imported bags start at a wall-clock instant, not 1970: the file's modification time minus
    the recording's length by default, or an ISO-8601 instant."""
    import os

    path = _write(tmp_path / "log.csv", _rows(100))
    mtime_ns = 1_700_000_000_000_000_000  # 2023-11-14T22:13:20Z
    os.utime(path, ns=(mtime_ns, mtime_ns))
    cols = ["--time-col", "t [s]", "--angle-col", "angle", "--angle-unit", "deg", "--pwm-col", "PWM",
            "--pwm-full-scale", "255"]
    assert main([str(path), "-o", str(tmp_path / "a"), *cols]) == 0
    back = read_bag(tmp_path / "a")
    assert back.stamp0_ns == mtime_ns - round(back.t[-1] * 1e9)  # the last sample at the file's time
    iso = ["--start-time", "2024-03-01T14:05:00+01:00"]
    assert main([str(path), "-o", str(tmp_path / "b"), *cols, *iso]) == 0
    assert read_bag(tmp_path / "b").stamp0_ns == 1_709_298_300_000_000_000
    assert main([str(path), "-o", str(tmp_path / "c"), *cols, "--start-time", "zero"]) == 0
    assert read_bag(tmp_path / "c").stamp0_ns == 0
    with pytest.raises(SystemExit):
        main([str(path), *cols, "--start-time", "yesterday"])


# ------------------------------------------------------------------ bad rows: cut, short, NaN/inf


@real_data
@pytest.mark.real_data
def test_aeroshield_cut_in_its_last_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """``head -c 60000 Identification_Data.csv``: the last line reads '2176,1.60886,0.5'."""
    cut = tmp_path / "t.csv"
    cut.write_bytes(AEROSHIELD.read_bytes()[:60000])
    with pytest.raises(CsvImportError) as err:
        import_csv(cut, "aeroshield_ident")
    assert str(err.value) == (f"{cut}:2178: row has 3 fields, expected 5 (last line cut: the file does not "
                              "end with a line break); csv_import --drop-bad-rows drops it")
    assert main([str(cut), "--preset", "aeroshield_ident", "-o", str(tmp_path / "X")]) == 1
    assert capsys.readouterr().err == f"csv_import: error: {err.value}\n"
    assert not (tmp_path / "X").exists()
    # dropped on request: the rows before it are those of the whole file, the last angle the true one
    dropped = r"t\.csv: dropped 1 bad row of 2177: line 2178 \(row has 3 fields"
    with pytest.warns(CsvRowWarning, match=dropped):
        rec = import_csv(cut, "aeroshield_ident", bad_rows="drop")
    full = import_csv(AEROSHIELD, "aeroshield_ident")
    assert len(rec) == 2176 and rec.channels["theta"][-1] == 0.561437
    assert np.array_equal(rec.channels["theta"], full.channels["theta"][:2176])
    assert np.array_equal(rec.duty, full.duty[:2176])
    assert rec.meta["dropped_rows"] == {"count": 1, "first": [
        {"line": 2178, "problem": "row has 3 fields, expected 5 (last line cut: the file does not end with a "
                                  "line break)"}]}
    assert main([str(cut), "--preset", "aeroshield_ident", "-o", str(tmp_path / "Y"), "--drop-bad-rows"]) == 0
    out = capsys.readouterr()
    assert out.err.startswith("csv_import: warning: ") and "dropped 1 bad row of 2177: line 2178" in out.err
    assert "2176 samples" in out.out and "1 bad row dropped" in out.out
    assert np.array_equal(read_bag(tmp_path / "Y").channels["theta"], rec.channels["theta"])


def test_every_cut_of_the_last_lines_is_refused_or_flagged(tmp_path: Path) -> None:
    """Cut a file at every byte of its last three lines: the import never returns a value the full
    file does not have without saying so. A cut after a line break imports the complete rows; a
    cut inside a line is an error naming that line, or (the row still has all its fields, e.g. the
    last number lost digits) a warning that the last row may be cut; --drop-bad-rows gives exactly
    the complete rows."""
    text = _rows(40)
    full = import_csv(_write(tmp_path / "full.csv", text), SPEC)
    lines = text.splitlines(keepends=True)
    start = len("".join(lines[:-3]))
    outcomes = {"complete": 0, "error": 0, "flagged": 0}
    for cut in range(start, len(text)):
        path = _write(tmp_path / f"cut{cut}.csv", text[:cut])
        done = text[:cut].count("\n")  # complete lines, header included
        n = done - 1
        if text[cut - 1] == "\n":
            rec = import_csv(path, SPEC)
            assert len(rec) == n and np.array_equal(rec.channels["theta"], full.channels["theta"][:n])
            outcomes["complete"] += 1
            continue
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            try:
                rec = import_csv(path, SPEC)
            except CsvImportError as exc:
                assert str(exc).startswith(f"{path}:{done + 1}: "), exc
                outcomes["error"] += 1
            else:
                assert [w.category for w in caught] == [CsvRowWarning]
                assert str(caught[0].message).startswith(f"{path}:{done + 1}: the file does not end with a "
                                                         "line break, so its last row")
                assert rec.meta["last_line_unterminated"] == done + 1
                outcomes["flagged"] += 1
        with pytest.warns(CsvRowWarning, match=rf"dropped 1 bad row of {n + 1}: line {done + 1} "):
            dropped = import_csv(path, SPEC, bad_rows="drop")
        assert len(dropped) == n and np.array_equal(dropped.channels["theta"], full.channels["theta"][:n])
    # 3 cuts after a line break; cuts inside the last number keep all fields and are flagged
    assert outcomes["complete"] == 3 and outcomes["error"] > 0 and outcomes["flagged"] > 0


@pytest.mark.parametrize(("row", "problem"), [
    ("0.10,103,nan", "column 'angle [deg]': 'nan' is not a finite number"),
    ("0.10,inf,-7.5", "column 'PWM [0-255]': 'inf' is not a finite number"),
    ("0.10,-Infinity,-7.5", "column 'PWM [0-255]': '-Infinity' is not a finite number"),
    ("0.10,103,-7.5,9", "row has 4 fields, expected 3"),
    ("0.10,103", "row has 2 fields, expected 3"),
    ("0.10,1O3,-7.5", "column 'PWM [0-255]': '1O3' is not a number"),
])
def test_bad_row_in_the_middle(tmp_path: Path, row: str, problem: str) -> None:
    lines = _rows(12).splitlines()
    lines[6] = row  # line 7
    path = _write(tmp_path / "mid.csv", "\n".join(lines) + "\n")
    with pytest.raises(CsvImportError) as err:
        import_csv(path, SPEC)
    assert str(err.value) == f"{path}:7: {problem}; csv_import --drop-bad-rows drops it"
    with pytest.warns(CsvRowWarning, match=rf"dropped 1 bad row of 12: line 7 \({re.escape(problem)}\)$"):
        rec = import_csv(path, SPEC, bad_rows="drop")
    assert len(rec) == 11 and rec.meta["rows"] == 11
    full = import_csv(_write(tmp_path / "ok.csv", _rows(12)), SPEC)
    keep = np.r_[0:5, 6:12]
    assert np.array_equal(rec.channels["theta"], full.channels["theta"][keep])


def test_many_bad_rows_counted_and_first_lines_listed(tmp_path: Path) -> None:
    lines = _rows(50).splitlines()
    for k in (4, 9, 10, 20, 30, 41, 45):
        lines[k - 1] = lines[k - 1] + ",extra"
    path = _write(tmp_path / "many.csv", "\n".join(lines) + "\n")
    with pytest.raises(CsvImportError) as err:
        import_csv(path, SPEC)
    assert str(err.value) == (f"{path}:4: row has 4 fields, expected 3; 7 bad rows in all, lines 4, 9, 10, "
                              "20, 30, ...; csv_import --drop-bad-rows drops them")
    with pytest.warns(CsvRowWarning, match=r"dropped 7 bad rows of 50: line 4 \(row has 4 fields, expected "
                                           r"3\); line 9 .*; line 30 \(.*\); \.\.\.$"):
        rec = import_csv(path, SPEC, bad_rows="drop")
    assert len(rec) == 43
    assert rec.meta["dropped_rows"]["count"] == 7
    assert [r["line"] for r in rec.meta["dropped_rows"]["first"]] == [4, 9, 10, 20, 30]


def test_optional_channel_may_be_empty_or_nan_but_not_inf(tmp_path: Path) -> None:
    spec = CsvSpec(time_col="t", input_col="u", angle_col="a", channels={"i_a": ("i", 1.0)})
    ok = _write(tmp_path / "ok.csv", "t,u,a,i\n0,0.1,0.0,0.5\n0.1,0.1,0.1,\n0.2,0.1,0.2,nan\n"
                                     "0.3,0.1,0.3,0.7\n")
    rec = import_csv(ok, spec)
    assert np.array_equal(rec.channels["i_a"], [0.5, np.nan, np.nan, 0.7], equal_nan=True)
    bad = _write(tmp_path / "inf.csv", "t,u,a,i\n0,0.1,0.0,0.5\n0.1,0.1,0.1,inf\n0.2,0.1,0.2,0.6\n")
    with pytest.raises(CsvImportError, match=r"inf\.csv:3: column 'i': 'inf' is not a finite number"):
        import_csv(bad, spec)


def test_empty_header_only_one_row(tmp_path: Path) -> None:
    with pytest.raises(CsvImportError) as err:
        import_csv(_write(tmp_path / "empty.csv", ""), SPEC)
    assert str(err.value) == f"{tmp_path / 'empty.csv'}: empty file (0 bytes)"
    with pytest.raises(CsvImportError, match=r"blank\.csv: no data lines \(only 0 comment and 2 blank"):
        import_csv(_write(tmp_path / "blank.csv", "\n \n"), SPEC)
    with pytest.raises(CsvImportError) as err:
        import_csv(_write(tmp_path / "hdr.csv", "t [s],PWM [0-255],angle [deg]\n"), SPEC)
    assert str(err.value) == f"{tmp_path / 'hdr.csv'}:1: header line but no data rows"
    with pytest.raises(CsvImportError) as err:
        import_csv(_write(tmp_path / "one.csv", _rows(1)), SPEC)
    assert str(err.value) == f"{tmp_path / 'one.csv'}: 1 data row (line 2); need at least 2 samples"
    # two rows, one of them bad and dropped: one left
    with pytest.warns(CsvRowWarning), pytest.raises(CsvImportError, match=r"1 data row .*need at least 2"):
        import_csv(_write(tmp_path / "two.csv", _rows(2, bad_line=3)), SPEC, bad_rows="drop")


def test_cut_gzip(tmp_path: Path) -> None:
    text = _rows(400)
    packed = gzip.compress(text.encode())
    path = tmp_path / "log.csv.gz"
    path.write_bytes(packed[: len(packed) * 2 // 3])
    with pytest.raises(CsvImportError) as err:
        import_csv(path, SPEC)
    assert str(err.value).startswith(f"{path}: the gzip stream is cut: it ends after {len(packed) * 2 // 3} "
                                     "compressed bytes without its end marker (")
    assert str(err.value).endswith("bytes of text readable); csv_import --drop-bad-rows imports the "
                                   "readable part")
    with pytest.warns(CsvRowWarning, match="dropped 1 bad row"):
        rec = import_csv(path, SPEC, bad_rows="drop")
    full = import_csv(_write(tmp_path / "full.csv", text), SPEC)
    n = len(rec)
    assert 0 < n < 400 and np.array_equal(rec.channels["theta"], full.channels["theta"][:n])
    # two gzip members (concatenated files) read whole; a corrupt one is named
    two = tmp_path / "two.csv.gz"
    head, tail = text.split("\n", 200)[:200], text.split("\n", 200)[200]
    two.write_bytes(gzip.compress(("\n".join(head) + "\n").encode()) + gzip.compress(tail.encode()))
    assert np.array_equal(import_csv(two, SPEC).channels["theta"], full.channels["theta"])
    bad = bytearray(packed)
    bad[len(bad) // 2] ^= 0xFF
    (tmp_path / "bad.csv.gz").write_bytes(bytes(bad))
    with pytest.raises(CsvImportError, match=r"bad\.csv\.gz: corrupt gzip data"):
        import_csv(tmp_path / "bad.csv.gz", SPEC)
