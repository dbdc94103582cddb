#!/usr/bin/env python3
"""Write (or check) the simulation reference of the shipped rigs: ``test/data/legacy_sim_reference.npz``.

The reference was written by this script on main 8559cc8, before the plant model moved onto the
component registry (issue 35), so ``test/test_model_registry.py`` can show that every shipped rig
file still simulates as it did. For each shipped rig two variants are simulated for 600 samples
at the rig's own sample period with a staircase duty cycle between the equilibria at 0.1 rad
and the highest of 0.9/0.7/0.5/0.3 rad that the rig can hold:

* ``as_shipped``: the rig file as it is;
* ``all_on``: every effect switched on (the legacy switch names ``viscous_friction`` and
  ``coulomb_friction`` turn on both the rod's and the rotor's half), with non-zero values for
  every effect parameter the file leaves at zero (dead zone, lag, a 2.5-sample delay, rotor and
  rod dry friction with a Stribeck part, end stops, thrust exponent 1.9), sensor noise and
  quantisation on (noise seed 3).

Stored: the state ``x`` and the measured channels, every 5th sample (a 150 kB file).

Usage: ``python tools/legacy_sim_reference.py [--write PATH] [--full PATH]`` (``--full``: every
sample of every array, for a bit-for-bit comparison outside the repository).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from aeropend_sim.model import PlantModel
from aeropend_sim.params import Rig, load_rig, shipped_rigs
from aeropend_sim.simulation import simulate

DEFAULT = Path(__file__).resolve().parents[1] / "test" / "data" / "legacy_sim_reference.npz"
N_SAMPLES = 600
DECIMATE = 5
CHANNELS = ("theta", "theta_dot", "i_a", "v_a", "omega_rotor", "omega_prop")


def duty_staircase(rig: Rig, n: int = N_SAMPLES, seed: int = 7) -> np.ndarray:
    """Random staircase between the duty cycles holding 0.1 rad and the highest holdable angle."""
    m = PlantModel(rig)
    lo = hi = m.equilibrium(0.1)[1]
    for th in (0.9, 0.7, 0.5, 0.3):
        try:
            hi = m.equilibrium(th)[1]
            break
        except ValueError:
            continue
    rng = np.random.default_rng(seed)
    out, k = [], 0
    while k < n:
        h = int(rng.integers(5, 60))
        out.append(np.full(h, rng.uniform(lo, hi)))
        k += h
    d = np.concatenate(out)[:n]
    d[: n // 10] = hi
    return d


def all_on(rig: Rig) -> Rig:
    """Every effect on, with a non-zero value for each effect parameter (module doc)."""
    dt = rig.sample_period
    p, m = rig.pendulum, rig.motor
    r = rig.with_effects(dead_zone=True, viscous_friction=True, coulomb_friction=True, propeller_drag=True,
                         thrust_exponent=True, actuator_lag=True, input_delay=True, end_stops=True,
                         sensor_noise=True, quantisation=True, back_emf=True, armature_inductance="dynamic")
    r = r.with_params("actuator", dead_zone=0.05, lag_time_constant=0.03, input_delay=2.5 * dt)
    r = r.with_params("motor", T_c=max(m.T_c, 0.006 * m.K_t), B_m=max(m.B_m, 1e-7), K_d=max(m.K_d, 1e-9))
    k = 200.0 * p.mgd_over_J
    r = r.with_params("pendulum", coulomb_over_J=0.02 * p.mgd_over_J, stribeck_over_J=0.03 * p.mgd_over_J,
                      stribeck_velocity=0.3, c_over_J=max(p.c_over_J, 0.5), theta_min=-0.2, theta_max=0.5,
                      stop_stiffness=k, stop_damping=2.0 * k**0.5)
    return r.with_params("thrust", exponent=1.9)


def reference(decimate: int = DECIMATE) -> dict[str, np.ndarray]:
    """``{"<rig>/<variant>/<array>": values}`` for every shipped rig (module doc)."""
    out: dict[str, np.ndarray] = {}
    for name in shipped_rigs():
        rig = load_rig(name)
        duty = duty_staircase(rig)
        for variant, r in (("as_shipped", rig), ("all_on", all_on(rig))):
            tr = simulate(r, duty, seed=3, backend="lsoda")  # the reference was written with LSODA
            ch = tr.channels()
            out[f"{name}/{variant}/x"] = tr.x[::decimate]
            for c in CHANNELS:
                if c in ch:
                    out[f"{name}/{variant}/{c}"] = ch[c][::decimate]
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--write", type=Path, default=None, help=f"write the reference (default {DEFAULT})")
    ap.add_argument("--full", type=Path, default=None, help="write every sample to this .npz instead")
    args = ap.parse_args()
    if args.full is not None:
        np.savez_compressed(args.full, **reference(decimate=1))
        print(f"written {args.full}")
        return
    path = args.write or DEFAULT
    np.savez_compressed(path, **reference())
    print(f"written {path}")


if __name__ == "__main__":
    main()
