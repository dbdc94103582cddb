"""Integrator kernels of the compiled backend: the text every generated module ends with.

Not used as a module: :mod:`.source` appends this file's text, from the marker line on, to
the module it generates for an actuator family, after that module's ``rhs``, ``contact`` and
``signals`` functions (the family's equations, written by
:func:`aeropend_sim.components.assembly.chain_source`) and its constant ``HAS_CONTACT``. Keeping
the kernels in a file of their own lets them be read, linted and versioned as code; the
generated module's name hashes this text, so a change here recompiles.

Scheme: classical RK4 with ``n`` equal sub-steps per constant-input piece of a sample. A sample
with a fractional input delay is two pieces, split where the delayed command switches (the
shifted zero-order hold of :func:`aeropend_sim.simulation.simulate`). A contact term (an end stop,
``Term.contact``) switches on with a jump of the right-hand side (its damping acts at full
strength from zero penetration) and off with a kink (the rebound brings the push to zero); a
fixed step across either is first or second order. A sub-step in which any RK4 stage point
lies on the other side of zero/non-zero contact force than its start is therefore redone: up to
the longest step whose stage points all stay on the starting side (bisection to 2⁻⁴⁰ of the
sub-step; testing the end alone is not enough, the fourth stage's predicted end point leads the
path by O(h³) and would see the jump), a step of 2⁻²⁰ of the sub-step across the switch, and the
rest, so RK4 keeps its order through contacts.
"""

# ruff: noqa: F821 - rhs, contact, signals and HAS_CONTACT are defined by the generated part

import math

import numpy as np
from numba import njit

# ---- generated modules include the text below this line ----

#: Bisections that locate a contact switching inside a sub-step (to 2**-40 of its length).
ONSET_BISECTIONS = 40
#: The step across a located switch, as a fraction of the sub-step: its first RK4 stage sees the
#: old side of the law (error ∝ this fraction × the jump); it must reach past the gap the bisection
#: leaves (a stage point's O(h³) lead on the path).
SWITCH_STEP = 2.0**-20
#: Switches handled inside one sub-step (more are integrated without location).
SWITCH_ROUNDS = 4

#: Output codes of :func:`outputs`: 0-4 the states; then the drive quantity, the armature current
#: (the algebraic one when quasi-static), the propeller speed and the thrust.
CODE_DRIVE, CODE_I_A, CODE_OMEGA_PROP, CODE_THRUST = 5, 6, 7, 8


@njit(error_model="numpy")
def _rk4(x0, x1, x2, x3, x4, u, p, h):
    hh = 0.5 * h
    a0, a1, a2, a3, a4 = rhs(x0, x1, x2, x3, x4, u, p)
    b0, b1, b2, b3, b4 = rhs(x0 + hh * a0, x1 + hh * a1, x2 + hh * a2, x3 + hh * a3, x4 + hh * a4, u, p)
    c0, c1, c2, c3, c4 = rhs(x0 + hh * b0, x1 + hh * b1, x2 + hh * b2, x3 + hh * b3, x4 + hh * b4, u, p)
    d0, d1, d2, d3, d4 = rhs(x0 + h * c0, x1 + h * c1, x2 + h * c2, x3 + h * c3, x4 + h * c4, u, p)
    s = h / 6.0
    return (x0 + s * (a0 + 2.0 * (b0 + c0) + d0), x1 + s * (a1 + 2.0 * (b1 + c1) + d1),
            x2 + s * (a2 + 2.0 * (b2 + c2) + d2), x3 + s * (a3 + 2.0 * (b3 + c3) + d3),
            x4 + s * (a4 + 2.0 * (b4 + c4) + d4))


@njit(inline="always", error_model="numpy")  # numba-level inlining: 8 % faster
def _rk4_on(x0, x1, x2, x3, x4, u, p, h, side, every):
    """:func:`_rk4` and whether its fourth stage's predicted end and (``every``) its two midpoints
    and its end lie on the contact side ``side`` (True: the contact force is non-zero there)."""
    hh = 0.5 * h
    a0, a1, a2, a3, a4 = rhs(x0, x1, x2, x3, x4, u, p)
    s1 = (x0 + hh * a0, x1 + hh * a1, x2 + hh * a2, x3 + hh * a3, x4 + hh * a4)
    on = not every or (contact(s1[0], s1[1], s1[2], s1[3], s1[4], u, p) != 0.0) == side
    b0, b1, b2, b3, b4 = rhs(s1[0], s1[1], s1[2], s1[3], s1[4], u, p)
    s2 = (x0 + hh * b0, x1 + hh * b1, x2 + hh * b2, x3 + hh * b3, x4 + hh * b4)
    on = on and (not every or (contact(s2[0], s2[1], s2[2], s2[3], s2[4], u, p) != 0.0) == side)
    c0, c1, c2, c3, c4 = rhs(s2[0], s2[1], s2[2], s2[3], s2[4], u, p)
    s3 = (x0 + h * c0, x1 + h * c1, x2 + h * c2, x3 + h * c3, x4 + h * c4)
    on = on and (contact(s3[0], s3[1], s3[2], s3[3], s3[4], u, p) != 0.0) == side
    d0, d1, d2, d3, d4 = rhs(s3[0], s3[1], s3[2], s3[3], s3[4], u, p)
    s = h / 6.0
    y = (x0 + s * (a0 + 2.0 * (b0 + c0) + d0), x1 + s * (a1 + 2.0 * (b1 + c1) + d1),
         x2 + s * (a2 + 2.0 * (b2 + c2) + d2), x3 + s * (a3 + 2.0 * (b3 + c3) + d3),
         x4 + s * (a4 + 2.0 * (b4 + c4) + d4))
    on = on and (not every or (contact(y[0], y[1], y[2], y[3], y[4], u, p) != 0.0) == side)
    return y, on


@njit(error_model="numpy")
def _across(x0, x1, x2, x3, x4, u, p, h):
    """A sub-step of length ``h`` during which the contact force switches between zero and
    non-zero (module doc): the longest step whose stage points all stay on the starting side
    (bisection), a step of SWITCH_STEP·h across the switch, then the rest, which is checked the
    same way (a second switch, or a switch the short step did not reach, starts another round)."""
    rem = h
    for _ in range(SWITCH_ROUNDS):
        side = contact(x0, x1, x2, x3, x4, u, p) != 0.0
        lo = 0.0
        hi = rem
        for _ in range(ONSET_BISECTIONS):
            mid = 0.5 * (lo + hi)
            if _rk4_on(x0, x1, x2, x3, x4, u, p, mid, side, True)[1]:
                lo = mid
            else:
                hi = mid
        if lo > 0.0:
            x0, x1, x2, x3, x4 = _rk4(x0, x1, x2, x3, x4, u, p, lo)
            rem -= lo
        tiny = min(rem, h * SWITCH_STEP)
        x0, x1, x2, x3, x4 = _rk4(x0, x1, x2, x3, x4, u, p, tiny)
        rem -= tiny
        if rem <= 1e-15 * h:
            return (x0, x1, x2, x3, x4)
        y, on = _rk4_on(x0, x1, x2, x3, x4, u, p, rem, contact(x0, x1, x2, x3, x4, u, p) != 0.0, True)
        if on:
            return y
    return _rk4(x0, x1, x2, x3, x4, u, p, rem)


@njit(inline="always", error_model="numpy")  # numba-level inlining: 8 % faster
def _substep(x0, x1, x2, x3, x4, u, p, h, side):
    """One sub-step from a state on contact side ``side``; returns the state and its side.

    Only the fourth stage's predicted end is tested here (one evaluation of the contact terms):
    the midpoints trail the path and the end is within O(h³) of the predicted end, so a switch
    shows there, except one so close to the end that the force it misses is negligible; the next
    sub-step then sees the new side and locates nothing more. Every stage point is tested while
    locating a switch (:func:`_across`).
    """
    y, on = _rk4_on(x0, x1, x2, x3, x4, u, p, h, side, False)
    if on:
        return y, side
    y = _across(x0, x1, x2, x3, x4, u, p, h)
    return y, contact(y[0], y[1], y[2], y[3], y[4], u, p) != 0.0


@njit(error_model="numpy")
def _advance(x0, x1, x2, x3, x4, ua, ub, p, n_a, h_a, n_b, h_b):
    if not HAS_CONTACT:
        for _ in range(n_a):
            x0, x1, x2, x3, x4 = _rk4(x0, x1, x2, x3, x4, ua, p, h_a)
        for _ in range(n_b):
            x0, x1, x2, x3, x4 = _rk4(x0, x1, x2, x3, x4, ub, p, h_b)
        return (x0, x1, x2, x3, x4)
    side = contact(x0, x1, x2, x3, x4, ua, p) != 0.0
    for _ in range(n_a):
        (x0, x1, x2, x3, x4), side = _substep(x0, x1, x2, x3, x4, ua, p, h_a, side)
    for _ in range(n_b):
        (x0, x1, x2, x3, x4), side = _substep(x0, x1, x2, x3, x4, ub, p, h_b, side)
    return (x0, x1, x2, x3, x4)


@njit(cache=True, nogil=True, error_model="numpy")
def step(x, ua, ub, p, n_a, h_a, n_b, h_b):
    """One sample from state ``x`` (5,): ``n_a`` sub-steps of ``h_a`` [s] with the command ``ua``
    the actuator still sees, then ``n_b`` of ``h_b`` with ``ub``. Returns the next state (5,)."""
    y = _advance(x[0], x[1], x[2], x[3], x[4], ua, ub, p, n_a, h_a, n_b, h_b)
    out = np.empty(5)
    for c in range(5):
        out[c] = y[c]
    return out


@njit(cache=True, nogil=True, error_model="numpy")
def replay(x0, duty, tau_before, whole, n_a, h_a, n_b, h_b, p, states, u_at, u_before):
    """Replay ``duty`` (N,) from ``x0`` (5,) with parameter vector ``p``.

    The actuator sees ``duty[j - whole - 1]`` on the first ``n_a`` sub-steps of sample j and
    ``duty[j - whole]`` on the other ``n_b`` (``tau_before`` before the first command). Fills
    ``states`` (N, 5), the state at each sample instant, ``u_at`` (N,), the command the actuator
    sees there, and ``u_before`` (N,), the one it saw just before (they differ where a command
    arrives at the instant). Returns -1, or the first sample whose state is not finite (the rest is
    unset).
    """
    n = duty.size
    x0_, x1, x2, x3, x4 = x0[0], x0[1], x0[2], x0[3], x0[4]
    for j in range(n):
        ja = j - whole - 1
        jb = j - whole
        ua = duty[ja] if ja >= 0 else tau_before
        ub = duty[jb] if jb >= 0 else tau_before
        if not math.isfinite(x0_ + x1 + x2 + x3 + x4):
            return j
        states[j, 0] = x0_
        states[j, 1] = x1
        states[j, 2] = x2
        states[j, 3] = x3
        states[j, 4] = x4
        u_at[j] = ua if n_a > 0 else ub
        u_before[j] = ua
        x0_, x1, x2, x3, x4 = _advance(x0_, x1, x2, x3, x4, ua, ub, p, n_a, h_a, n_b, h_b)
    return -1


@njit(cache=True, nogil=True, error_model="numpy")
def outputs(states, u_at, u_before, p, codes, out):
    """Fill ``out`` (C, N) with the channels ``codes`` (C,) of a replay (see the CODE_* constants).

    The armature current is the one at the instant, before a command arriving there acts
    (``u_before``): the state when dynamic, and when quasi-static the algebraic current of the
    command held until then (the limit of the dynamic current as L_a → 0); the other derived
    channels follow ``u_at``."""
    derived = False
    current = False
    for c in codes:
        derived = derived or c >= 5
        current = current or c == CODE_I_A
    sig = (0.0, 0.0, 0.0, 0.0, 0.0)
    i_a = 0.0
    for j in range(u_at.size):
        if derived:
            sig = signals(states[j, 0], states[j, 1], states[j, 2], states[j, 3], states[j, 4], u_at[j], p)
            i_a = sig[CODE_I_A - 4]
        if current and u_before[j] != u_at[j]:
            i_a = signals(states[j, 0], states[j, 1], states[j, 2], states[j, 3], states[j, 4], u_before[j],
                          p)[CODE_I_A - 4]
        for k in range(codes.size):
            c = codes[k]
            out[k, j] = states[j, c] if c < 5 else (i_a if c == CODE_I_A else sig[c - 4])


@njit(cache=True, nogil=True, error_model="numpy")
def replay_batch(x0, duty, tau_before, whole, n_a, h_a, n_b, h_b, p, codes, out, failed, start, stop):
    """:func:`replay` and :func:`outputs` for rows ``start`` to ``stop - 1`` of ``p`` (B, P) and
    ``x0`` (B, 5), each with its own sub-step plan (``whole``, ``n_a``, ``h_a``, ``n_b``, ``h_b``:
    (B,)); ``out`` (B, C, N), ``failed`` (B,) as :func:`replay` returns. Releases the GIL, so
    threads can run disjoint row ranges at once (:meth:`CompiledPlant.replay_batch`)."""
    n = duty.size
    states = np.empty((n, 5))
    u_at = np.empty(n)
    u_before = np.empty(n)
    for b in range(start, stop):
        failed[b] = replay(x0[b], duty, tau_before, whole[b], n_a[b], h_a[b], n_b[b], h_b[b], p[b], states,
                           u_at, u_before)
        if failed[b] < 0:
            outputs(states, u_at, u_before, p[b], codes, out[b])


@njit(cache=True, nogil=True, error_model="numpy")
def derivatives(x, u, p, out, drive):
    """Fill ``out`` (N, 5) with the right-hand side dx/dt at the states ``x`` (N, 5) and commands
    ``u`` (N,) (the command reaching the actuator), and ``drive`` (N,) with the drive quantity there
    (v_a or the ESC's set-point, of the command past the lag and the duty transforms: the second
    value of :func:`signals`)."""
    for j in range(x.shape[0]):
        d = rhs(x[j, 0], x[j, 1], x[j, 2], x[j, 3], x[j, 4], u[j], p)
        drive[j] = signals(x[j, 0], x[j, 1], x[j, 2], x[j, 3], x[j, 4], u[j], p)[1]
        for c in range(5):
            out[j, c] = d[c]


@njit(cache=True, nogil=True, error_model="numpy")
def jacobians(x, u, p):
    """Central-difference Jacobians ∂rhs/∂x (B, R, 5, 5) at the states ``x`` (R, 5) and commands
    ``u`` (R,) for each parameter row of ``p`` (B, P) (step 1e-6·max(1, |x|))."""
    out = np.zeros((p.shape[0], x.shape[0], 5, 5))
    for b in range(p.shape[0]):
        for r in range(x.shape[0]):
            for c in range(5):
                h = 1e-6 * max(1.0, abs(x[r, c]))
                hi = x[r].copy()
                lo = x[r].copy()
                hi[c] += h
                lo[c] -= h
                fh = rhs(hi[0], hi[1], hi[2], hi[3], hi[4], u[r], p[b])
                fl = rhs(lo[0], lo[1], lo[2], lo[3], lo[4], u[r], p[b])
                for k in range(5):
                    out[b, r, k, c] = (fh[k] - fl[k]) / (2.0 * h)
    return out
