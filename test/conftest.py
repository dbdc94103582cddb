"""Shared fixtures."""

from __future__ import annotations

from collections.abc import Callable, Sequence

import pytest

#: Columns of a CSV log written by ``bench/truth_plant.py`` (``TruthRecording.to_csv``).
TRUTH_CSV_COLUMNS = {"i_a": "i_a_A", "v_a": "v_a_V", "omega_rotor": "omega_rad_s"}


@pytest.fixture
def truth_csv_preset(monkeypatch: pytest.MonkeyPatch) -> Callable[..., str]:
    """Register a ``csv_import`` preset for the independent truth plant's CSV logs, for this test.

    Call it with a preset name and the extra channels to read (default i_a, v_a, ω₁); it returns
    the name (for ``FILE.csv:NAME`` arguments). The preset is removed after the test.
    """
    from aeropend_ident import csv_import
    from aeropend_ident.csv_import import CsvSpec

    def register(name: str, channels: Sequence[str] = tuple(TRUTH_CSV_COLUMNS)) -> str:
        spec = CsvSpec(angle_col="theta_rad", angle_unit="rad", time_col="time_s", time_unit="s",
                       input_col="duty", input_kind="duty",
                       channels={c: (TRUTH_CSV_COLUMNS[c], 1.0) for c in channels})
        monkeypatch.setitem(csv_import.PRESETS, name, spec)
        return name

    return register
