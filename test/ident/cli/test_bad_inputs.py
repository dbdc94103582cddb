"""Bad inputs at the command line: one row per case, each run as its console script in a subprocess.

Every row gives the command line, the exit code and the first line of stderr the user sees, and
no row may print a Python traceback. To add a case, add a :class:`Case` to :data:`CASES` (and,
if it needs an input file, a line to the ``inputs`` fixture). In the texts, ``{tmp}`` is the
folder of the inputs, ``{shared}`` the real recordings' folder, and ``{name}`` any value the
fixture computes (e.g. ``{mcap_size}``); an expected stderr line ending in ``...`` is a prefix.
"""

from __future__ import annotations

import importlib.resources
import os
import shutil
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from aeropend_ident.io.bag_writer import write_bag
from aeropend_ident.io.csv_import import PRESETS
from aeropend_sim.params import shipped_rigs
from aeropend_sim.recording import Recording

SHARED = Path(__file__).resolve().parents[4] / "shared" / "data" / "real"
AEROSHIELD = SHARED / "gergelytakacs__AutomationShield" / "AeroShield" / "Identification_Data.csv"
IMC = SHARED / "BA-Etchepareborda__adaptive-control-aeropendulum" / "closedloop_IMC_reference_steps.csv"
BIN = Path(sys.executable).parent

#: Console script -> module run with ``python -m`` when the script is not installed beside python.
MODULES = {
    "csv_import": "aeropend_ident.cli.csv_import",
    "identify": "aeropend_ident.cli.identify",
    "gap": "aeropend_ident.cli.gap",
    "compare": "aeropend_ident.cli.compare",
    "baseline": "aeropend_ident.cli.baseline",
    "reindex": "aeropend_ident.cli.reindex",
    "play": "aeropend_ident.nodes.play",
}


@dataclass(frozen=True)
class Case:
    """One bad input: the command line, what it must answer, and what it needs.

    Attributes
    ----------
    id : str
        Test id.
    argv : tuple of str
        Console script and arguments (placeholders as in the module docstring).
    rc : int
        Expected exit status.
    stderr : str
        Expected first line of stderr (``...`` at the end: a prefix).
    needs_shared : bool
        The case reads ``../shared`` (skipped with a reason when absent).
    """

    id: str
    argv: tuple[str, ...]
    rc: int
    stderr: str
    needs_shared: bool = False


def _csv(name: str) -> tuple[str, ...]:
    return ("csv_import", f"{{tmp}}/{name}", "--time-col", "t", "--duty-col", "u", "--angle-col", "a")


_DROP = "csv_import --drop-bad-rows drops it"
_LAST_CUT = "(last line cut: the file does not end with a line break)"

CASES: tuple[Case, ...] = (
    # --- CSV rows
    Case("csv-cut-last-line", _csv("cut.csv"), 1,
         f"csv_import: error: {{tmp}}/cut.csv:7: row has 2 fields, expected 3 {_LAST_CUT}; {_DROP}"),
    Case("csv-cut-last-line-dropped", (*_csv("cut.csv"), "--drop-bad-rows"), 0,
         f"csv_import: warning: {{tmp}}/cut.csv: dropped 1 bad row of 6: line 7 (row has 2 fields, "
         f"expected 3 {_LAST_CUT})"),
    Case("csv-aeroshield-cut-60000-bytes",
         ("csv_import", "{tmp}/t.csv", "--preset", "aeroshield_ident", "-o", "{tmp}/X"), 1,
         f"csv_import: error: {{tmp}}/t.csv:2178: row has 3 fields, expected 5 {_LAST_CUT}; {_DROP}",
         needs_shared=True),
    Case("csv-last-line-without-line-break", _csv("noeol.csv"), 0,
         "csv_import: warning: {tmp}/noeol.csv:4: the file does not end with a line break, so its last row "
         f"('0.02,0.1,0.3') may be cut; check it against the source ({_DROP})"),
    Case("csv-nan", _csv("nan.csv"), 1,
         f"csv_import: error: {{tmp}}/nan.csv:4: column 'a': 'nan' is not a finite number; {_DROP}"),
    Case("csv-inf", _csv("inf.csv"), 1,
         f"csv_import: error: {{tmp}}/inf.csv:3: column 'u': '-inf' is not a finite number; {_DROP}"),
    Case("csv-extra-field", _csv("extra.csv"), 1,
         f"csv_import: error: {{tmp}}/extra.csv:3: row has 4 fields, expected 3; {_DROP}"),
    Case("csv-empty-file", _csv("empty.csv"), 1, "csv_import: error: {tmp}/empty.csv: empty file (0 bytes)"),
    Case("csv-header-only", _csv("header.csv"), 1,
         "csv_import: error: {tmp}/header.csv:1: header line but no data rows"),
    Case("csv-one-row", _csv("one.csv"), 1,
         "csv_import: error: {tmp}/one.csv: 1 data row (line 2); need at least 2 samples"),
    Case("csv-cut-gzip", _csv("cut.csv.gz"), 1,
         "csv_import: error: {tmp}/cut.csv.gz: the gzip stream is cut: it ends after {gz_size} compressed "
         "bytes without its end marker (..."),
    Case("csv-unknown-preset", ("csv_import", "{tmp}/one.csv", "--preset", "nope"), 1,
         f"csv_import: error: unknown preset 'nope'; available: {sorted(PRESETS)} (or a preset file: "
         "my_rig.yaml)"),
    Case("identify-csv-unknown-preset", ("identify", "{tmp}/one.csv:nope", "--rig", "thesis_sim", "--quiet",
                                         "--out", "{tmp}/o-preset"), 2,
         f"identify: error: {{tmp}}/one.csv:nope: unknown preset 'nope' after ':'; expected FILE:PRESET "
         f"with a preset of {sorted(PRESETS)}, a preset file (my_rig.yaml) or 'auto'"),
    # --- a lab's preset file (docs/csv_import.md): the message names the file, the key, the expectation
    Case("csv-user-preset-unknown-key", ("csv_import", "{tmp}/rows.csv", "--preset", "{tmp}/typo.yaml"), 1,
         "csv_import: error: preset file {tmp}/typo.yaml: unknown key 'input_colum'; did you mean "
         "'input_col'? the keys are angle_col, angle_unit, ..."),
    Case("csv-user-preset-wrong-value",
         ("csv_import", "{tmp}/rows.csv", "--preset", "{tmp}/esc_no_span.yaml"), 1,
         "csv_import: error: preset file {tmp}/esc_no_span.yaml: input_kind 'pulse_width_ms' needs "
         "input_span [ms]: the full-throttle minus zero-throttle pulse width of the ESC calibration (e.g. "
         "1.2 ms for a 1.1-2.3 ms range)"),
    Case("csv-user-preset-not-yaml", ("csv_import", "{tmp}/rows.csv", "--preset", "{tmp}/broken.yaml"), 1,
         "csv_import: error: preset file {tmp}/broken.yaml:4: not valid YAML (expected ',' or ']', but got "
         "'<stream end>', in a flow sequence that starts on line 3)"),
    Case("csv-user-preset-missing", ("csv_import", "{tmp}/rows.csv", "--preset", "{tmp}/absent.yaml"), 1,
         "csv_import: error: preset file {tmp}/absent.yaml: cannot read (No such file or directory); "
         "expected a YAML file with the keys of docs/csv_import.md"),
    Case("gap-csv-user-preset-bad", ("gap", "{tmp}/rows.csv:{tmp}/typo.yaml", "--rig", "thesis_sim", "-o",
                                     "{tmp}/o-userpreset"), 2,
         "gap: error: preset file {tmp}/typo.yaml: unknown key 'input_colum'; did you mean 'input_col'? ..."),
    Case("csv-write-preset-exists", (*_csv("rows.csv"), "--write-preset", "{tmp}/typo.yaml"), 1,
         "csv_import: error: --write-preset {tmp}/typo.yaml already exists; choose another name or pass "
         "--overwrite"),
    # --- no actuator command logged: a reference is not an input
    Case("csv-reference-only-refused", ("csv_import", "{tmp}/imc_reference_only.csv", "--time-col", "0",
                                        "--angle-col", "theta", "--reference-col", "theta_ref",
                                        "--input-constant", "0", "--input-kind", "pwm"), 1,
         "csv_import: error: {tmp}/imc_reference_only.csv: a constant input (input_constant = 0 counts "
         "(pwm): duty 0) cannot explain this log: θ turns back up at 0.8073 rad (t = 123.640 s), 0.46 rad "
         "above its final angle θ_f = 0.3476 rad, but under a constant input the rod turns back only beyond "
         "its equilibrium (at a turning point θ̇ = 0 and only the static torque acts, which points toward the "
         "equilibrium). The reference column 'theta_ref [rad]' is not an input: ...", needs_shared=True),
    Case("csv-reference-as-input-refused", ("csv_import", "{tmp}/imc_reference_only.csv", "--time-col", "0",
                                            "--angle-col", "theta", "--reference-col", "theta_ref",
                                            "--input-col", "theta_ref", "--input-kind", "duty"), 1,
         "csv_import: error: CsvSpec cli: reference_col and input_col are the same column 'theta_ref'; a "
         "reference is not an input (log the actuator command)", needs_shared=True),
    # --- rigs
    Case("identify-unknown-rig", ("identify", "{tmp}/bag", "--rig", "nope", "--quiet", "--out", "{tmp}/o1"),
         2, f"identify: error: no rig named 'nope'; shipped rigs are {shipped_rigs()} (or give a path to a "
            ".yaml file)"),
    Case("gap-unknown-rig", ("gap", "{tmp}/bag", "--rig", "nope", "-o", "{tmp}/o2"), 2,
         f"gap: error: unknown rig 'nope'; expected a rig-file path (.yaml) or one of {shipped_rigs()}"),
    Case("identify-negative-rig-parameter", ("identify", "{tmp}/bag", "--rig", "{tmp}/negative.yaml",
                                             "--quiet", "--out", "{tmp}/o3"), 2,
         "identify: error: {tmp}/negative.yaml: motor.R_a = -2.0 must be > 0 (armature resistance)"),
    Case("identify-missing-rig-parameter", ("identify", "{tmp}/bag", "--rig", "{tmp}/missing.yaml", "--quiet",
                                            "--out", "{tmp}/o4"), 2,
         "identify: error: {tmp}/missing.yaml: missing motor.K_t [N*m/A] (torque constant K_t)"),
    Case("gap-negative-rig-parameter", ("gap", "{tmp}/bag", "--rig", "{tmp}/negative.yaml", "-o", "{tmp}/o5"),
         2, "gap: error: rig {tmp}/negative.yaml: {tmp}/negative.yaml: motor.R_a = -2.0 must be > 0 "
            "(armature resistance)"),
    Case("compare-missing-rig-parameter", ("compare", "{tmp}/bag", "--rig", "{tmp}/missing.yaml", "-o",
                                           "{tmp}/o6"), 2,
         "compare: error: rig {tmp}/missing.yaml: {tmp}/missing.yaml: missing motor.K_t [N*m/A] (torque "
         "constant K_t)"),
    # --- bags
    Case("truncated-mcap", ("compare", "{tmp}/cut_mcap", "--rig", "thesis_sim", "--no-plots", "-o",
                            "{tmp}/o7"), 0,
         "compare: warning: bag '{tmp}/cut_mcap' is truncated: cut_mcap.mcap ends at byte {mcap_cut} without "
         "its MCAP footer (complete records up to byte {mcap_readable}); recovered {mcap_recovered} "
         "message(s) (..."),
    Case("truncated-db3", ("compare", "{tmp}/cut_sqlite3", "--rig", "thesis_sim", "--no-plots", "-o",
                           "{tmp}/o8"), 0,
         "compare: warning: bag '{tmp}/cut_sqlite3' is truncated: cut_sqlite3.db3 has {db3_cut} bytes but "
         "its SQLite header declares {db3_size} (read {db3_readable} bytes of whole pages); recovered "
         "{db3_recovered} message(s) (..."),
    Case("truncated-mcap-nothing-left", ("identify", "{tmp}/cut_header", "--rig", "thesis_sim", "--quiet",
                                         "--out", "{tmp}/o9"), 2,
         "identify: error: bag '{tmp}/cut_header' is truncated: cut_header.mcap ends at byte 100 without its "
         "MCAP footer (complete records up to byte {header_readable}); no complete message could be "
         "recovered"),
    Case("missing-metadata", ("identify", "{tmp}/nometa", "--rig", "thesis_sim", "--quiet", "--out",
                              "{tmp}/o10"), 2,
         "identify: error: bag '{tmp}/nometa' has no metadata.yaml: give its storage file instead "
         "({tmp}/nometa/nometa.mcap) or rebuild the metadata with 'reindex {tmp}/nometa'"),
    Case("play-missing-metadata", ("play", "{tmp}/nometa"), 1,
         "play: error: bag '{tmp}/nometa' has no metadata.yaml: give its storage file instead "
         "({tmp}/nometa/nometa.mcap) or rebuild the metadata with 'reindex {tmp}/nometa'"),
    Case("reindex-existing-metadata", ("reindex", "{tmp}/bag"), 1,
         "reindex: error: '{tmp}/bag/metadata.yaml' already exists; reindex --overwrite replaces it"),
    # --- an existing output folder: refused before any work, nothing in it touched
    *(Case(f"{cmd}-existing-output-folder", (cmd, *args, "-o", "{tmp}/out"), rc,
           f"{cmd}: error: output folder {{tmp}}/out/ exists and is not empty (notes.txt, report.json); "
           "pass --overwrite to replace it or choose another -o")
      for cmd, args, rc in (("gap", ("{tmp}/bag", "--rig", "thesis_sim"), 2),
                            ("baseline", ("{tmp}/bag", "--rig", "thesis_sim"), 2),
                            ("compare", ("{tmp}/bag", "--rig", "thesis_sim"), 2),
                            ("identify", ("{tmp}/bag",), 2))),
    Case("csv-existing-output-folder", (*_csv("rows.csv"), "-o", "{tmp}/out"), 1,
         "csv_import: error: bag folder {tmp}/out/ exists and is not empty (notes.txt, report.json); "
         "pass --overwrite to replace it or choose another -o"),
    Case("gap-overwrite-a-folder-it-did-not-write", ("gap", "{tmp}/bag", "--rig", "thesis_sim", "-o",
                                                      "{tmp}/notmine", "--overwrite"), 2,
         "gap: error: output folder {tmp}/notmine/ ..."),
    Case("reindex-not-a-directory", ("reindex", "{tmp}/nowhere"), 1,
         "reindex: error: '{tmp}/nowhere' is not a bag directory (it does not exist)"),
    # --- issue 62: corrupt chunks, an empty storage file, binary "CSV" files
    Case("corrupt-mcap-chunk", ("identify", "{tmp}/flipped_mcap", "--rig", "thesis_sim", "--quiet", "--out",
                                "{tmp}/o11"), 2,
         "identify: error: bag '{tmp}/flipped_mcap' is corrupt: reading failed (ReaderError: Chunk checksum "
         "mismatch.); flipped_mcap.mcap bytes {flipped_start}-{flipped_end} (log time ..."),
    Case("corrupt-db3-page", ("compare", "{tmp}/flipped_db3", "--rig", "thesis_sim", "--no-plots", "-o",
                              "{tmp}/o12"), 2,
         "compare: error: bag '{tmp}/flipped_db3' is corrupt: ..."),
    Case("reindex-empty-storage", ("reindex", "{tmp}/empty_bag"), 1,
         "reindex: error: '{tmp}/empty_bag/empty_bag.mcap' is empty: nothing was written (0 bytes: the "
         "recorder stopped or was killed before its first flush)"),
    Case("csv-nul-file", (*_csv("zeros.csv"), "-o", "{tmp}/o13"), 1,
         "csv_import: error: {tmp}/zeros.csv:1: a NUL byte at byte 0 of the text: this is a binary file, not "
         "a CSV text log (a UTF-16 export? save it as UTF-8 CSV)"),
)


def _recording(n: int = 1500) -> Recording:
    """A small excited run (θ, i_a; duty steps) as the simulator would record it."""
    t = np.arange(n) * 0.01
    duty = 0.3 + 0.1 * (np.floor(t / 1.5) % 3)
    theta = 0.4 + 0.2 * np.sin(t)
    return Recording(t=t, duty=duty, channels={"theta": theta, "i_a": 0.5 + 0.1 * np.cos(t)},
                     source="synthetic", stamp0_ns=1_700_000_000_000_000_000)


def _cut_bag(bag: Path, dest: Path, nbytes: int) -> tuple[int, int]:
    """``dest``: ``bag`` with its storage file cut to ``nbytes``; returns (cut size, full size)."""
    shutil.copytree(bag, dest)
    (src,) = [p for p in dest.iterdir() if p.suffix in (".mcap", ".db3")]
    data = src.read_bytes()
    src.write_bytes(data[:nbytes])
    src.rename(dest / f"{dest.name}{src.suffix}")
    meta = dest / "metadata.yaml"
    meta.write_text(meta.read_text().replace(src.name, f"{dest.name}{src.suffix}"))
    return nbytes, len(data)


@pytest.fixture(scope="module")
def inputs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, str]:
    """Write every input file of :data:`CASES`; returns the placeholder values."""
    from aeropend_ident.io.bag_recover import scan_storage

    tmp = tmp_path_factory.mktemp("bad")
    rows = "t,u,a\n" + "".join(f"{0.01 * k:.2f},0.1,{0.1 * k:.1f}\n" for k in range(5))
    (tmp / "cut.csv").write_text(rows + "0.05,0.1")
    (tmp / "noeol.csv").write_text("t,u,a\n0,0.1,0.2\n0.01,0.1,0.1\n0.02,0.1,0.3")
    (tmp / "nan.csv").write_text(rows.replace("0.02,0.1,0.2", "0.02,0.1,nan"))
    (tmp / "inf.csv").write_text(rows.replace("0.01,0.1,0.1", "0.01,-inf,0.1"))
    (tmp / "extra.csv").write_text(rows.replace("0.01,0.1,0.1", "0.01,0.1,0.1,7"))
    (tmp / "empty.csv").write_bytes(b"")
    (tmp / "header.csv").write_text("t,u,a\n")
    (tmp / "one.csv").write_text("t,u,a\n0,0.1,0.2\n")
    (tmp / "rows.csv").write_text(rows)
    for folder, names in (("out", ("report.json", "notes.txt")), ("notmine", ("notes.txt",))):
        (tmp / folder).mkdir()
        for name in names:
            (tmp / folder / name).write_text("a user's earlier result\n")
    import gzip

    long_rows = "t,u,a\n" + "".join(f"{0.01 * k:.2f},{0.1 + 0.01 * (k % 7):.2f},{np.sin(k):.6f}\n"
                                     for k in range(2000))
    packed = gzip.compress(long_rows.encode())
    (tmp / "cut.csv.gz").write_bytes(packed[: len(packed) // 2])
    if AEROSHIELD.is_file():
        (tmp / "t.csv").write_bytes(AEROSHIELD.read_bytes()[:60000])
    if IMC.is_file():  # the closed-loop log without its command column: only the reference is left
        lines = IMC.read_text(encoding="utf-8").splitlines()
        (tmp / "imc_reference_only.csv").write_text(
            "".join(",".join(f for i, f in enumerate(ln.split(",")) if i != 1) + "\n" for ln in lines))
    (tmp / "typo.yaml").write_text("angle_col: a\ntime_col: t\ninput_colum: u\n")
    (tmp / "esc_no_span.yaml").write_text("angle_col: a\ntime_col: t\ninput_col: u\n"
                                          "input_kind: pulse_width_ms\ninput_offset: 1.1\n")
    (tmp / "broken.yaml").write_text("angle_col: a\ntime_col: t\ninput_col: [u\n")
    rig = importlib.resources.files("aeropend_sim") / "rigs" / "thesis_sim.yaml"
    text = rig.read_text(encoding="utf-8")
    (tmp / "negative.yaml").write_text(text.replace("  R_a: {value: 2.0,", "  R_a: {value: -2.0,"))
    (tmp / "missing.yaml").write_text("".join(ln for ln in text.splitlines(keepends=True)
                                              if not ln.startswith("  K_t:")))
    rec = _recording()
    bag = write_bag(rec, tmp / "bag")
    db3 = write_bag(rec, tmp / "bag_db3", storage="sqlite3")
    values = {"tmp": str(tmp), "shared": str(SHARED), "gz_size": str(len(packed) // 2)}
    for name, src in (("mcap", bag), ("db3", db3)):
        dest = tmp / ("cut_mcap" if name == "mcap" else "cut_sqlite3")
        size = sum(p.stat().st_size for p in src.iterdir() if p.suffix in (".mcap", ".db3"))
        cut, full = _cut_bag(src, dest, size // 2)
        scan = scan_storage(next(p for p in dest.iterdir() if p.suffix in (".mcap", ".db3")))
        values.update({f"{name}_cut": str(cut), f"{name}_size": str(full),
                       f"{name}_readable": str(scan.readable_bytes), f"{name}_recovered": str(scan.total)})
    _cut_bag(bag, tmp / "cut_header", 100)
    values["header_readable"] = str(scan_storage(tmp / "cut_header" / "cut_header.mcap").readable_bytes)
    from aeropend_ident.io.bag_recover import scan_storage as scan_file

    flipped = write_bag(_recording(12000), tmp / "flipped_mcap") / "flipped_mcap.mcap"
    start, end = scan_file(flipped, keep_messages=False).chunks[2][:2]
    data = bytearray(flipped.read_bytes())
    data[(start + end) // 2:(start + end) // 2 + 64] = b"\xa5" * 64
    flipped.write_bytes(bytes(data))
    values.update({"flipped_start": str(start), "flipped_end": str(end)})
    db3 = write_bag(_recording(6000), tmp / "flipped_db3", storage="sqlite3") / "flipped_db3.db3"
    data = bytearray(db3.read_bytes())
    page = int.from_bytes(data[16:18], "big")
    at = len(data) // page // 2 * page
    data[at:at + 12] = b"\xff" * 12  # a b-tree page header
    db3.write_bytes(bytes(data))
    (tmp / "empty_bag").mkdir()
    (tmp / "empty_bag" / "empty_bag.mcap").write_bytes(b"")
    (tmp / "zeros.csv").write_bytes(b"\x00" * 65536)
    nometa = tmp / "nometa"
    shutil.copytree(bag, nometa)
    (nometa / "metadata.yaml").unlink()
    (nometa / "bag.mcap").rename(nometa / "nometa.mcap")
    return values


def _command(argv: tuple[str, ...], values: dict[str, str]) -> list[str]:
    exe = shutil.which(argv[0], path=str(BIN))
    head = [exe] if exe else [sys.executable, "-m", MODULES[argv[0]]]
    return head + [a.format(**values) for a in argv[1:]]


@pytest.mark.parametrize("case", CASES, ids=[c.id for c in CASES])
def test_bad_input(case: Case, inputs: dict[str, str]) -> None:
    if case.needs_shared and not AEROSHIELD.is_file():
        pytest.skip(f"real recordings not found at {SHARED}")
    env = {**os.environ, "MPLBACKEND": "Agg"}
    done = subprocess.run(_command(case.argv, inputs), capture_output=True, text=True, timeout=180, env=env,
                          cwd=inputs["tmp"])
    output = done.stdout + done.stderr
    assert "Traceback" not in output, output
    first = done.stderr.splitlines()[0] if done.stderr else ""
    expected = case.stderr.format(**inputs)
    if expected.endswith("..."):
        assert first.startswith(expected[:-3]), first
    else:
        assert first == expected
    assert done.returncode == case.rc, output
    for folder in ("out", "notmine"):  # a refused run leaves an existing folder as it was
        for name in os.listdir(Path(inputs["tmp"]) / folder):
            assert (Path(inputs["tmp"]) / folder / name).read_text() == "a user's earlier result\n"
