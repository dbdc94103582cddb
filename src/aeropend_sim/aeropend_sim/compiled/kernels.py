"""Integrator kernels of the compiled backend: the text every generated module ends with.

Not used as a module: :mod:`.source` appends this file's text, from the marker line on, to
the module it generates for an actuator family and a state layout, after that module's ``rhs``,
``contact`` and ``signals`` functions (the family's equations, written by
:func:`aeropend_sim.components.assembly.chain_source`), its constants ``HAS_CONTACT`` and
``N_STATE`` (the state's length, :mod:`aeropend_sim.components.states`) and its helpers on a state
held as a tuple of ``N_STATE`` floats: ``_axpy(x, h, a)`` (x + h·a), ``_rk4_end(x, s, a, b, c, d)``
(x + s·(a + 2(b + c) + d)), ``_load(v)`` (a row as a tuple) and ``_finite(x)``, each written out
entry by entry so the arithmetic is the same floating-point operations whatever the length. Keeping
the kernels in a file of their own lets them be read, linted and versioned as code; the generated
module's name hashes this text, so a change here recompiles.

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

# ruff: noqa: F821 - rhs, contact, signals, HAS_CONTACT, N_STATE and the state helpers are defined by the
# generated part (which imports OMEGA and TAU_F as this file does)

import numpy as np
from numba import njit

from aeropend_sim.components.states import N_CHAIN, OMEGA, TAU_F

#: The generated part sets the rig's state length; this one lets the file import as a module.
N_STATE = N_CHAIN

# ---- generated modules include the text below this line ----

#: Bisections that locate a contact switching inside a sub-step (to 2**-40 of its length).
ONSET_BISECTIONS = 40
#: The step across a located switch, as a fraction of the sub-step: its first RK4 stage sees the
#: old side of the law (error ∝ this fraction × the jump); it must reach past the gap the bisection
#: leaves (a stage point's O(h³) lead on the path).
SWITCH_STEP = 2.0**-20
#: Switches handled inside one sub-step (more are integrated without location).
SWITCH_ROUNDS = 4

#: Output codes of :func:`outputs`: 0 … N_STATE − 1 the states; then the drive quantity, the
#: armature current (the algebraic one when quasi-static), the propeller speed and the thrust,
#: which are entries 1-4 of :func:`signals`.
CODE_DRIVE, CODE_I_A, CODE_OMEGA_PROP, CODE_THRUST = N_STATE, N_STATE + 1, N_STATE + 2, N_STATE + 3
#: Entry of :func:`signals` of output code c ≥ N_STATE.
SIGNAL_OFFSET = N_STATE - 1


@njit(error_model="numpy")
def _rk4(x, u, p, h):
    hh = 0.5 * h
    a = rhs(x, u, p)
    b = rhs(_axpy(x, hh, a), u, p)
    c = rhs(_axpy(x, hh, b), u, p)
    d = rhs(_axpy(x, h, c), u, p)
    return _rk4_end(x, h / 6.0, a, b, c, d)


@njit(inline="always", error_model="numpy")  # numba-level inlining: 8 % faster
def _rk4_on(x, u, p, h, side, every):
    """:func:`_rk4` and whether its fourth stage's predicted end and (``every``) its two midpoints
    and its end lie on the contact side ``side`` (True: the contact force is non-zero there)."""
    hh = 0.5 * h
    a = rhs(x, u, p)
    s1 = _axpy(x, hh, a)
    on = not every or (contact(s1, u, p) != 0.0) == side
    b = rhs(s1, u, p)
    s2 = _axpy(x, hh, b)
    on = on and (not every or (contact(s2, u, p) != 0.0) == side)
    c = rhs(s2, u, p)
    s3 = _axpy(x, h, c)
    on = on and (contact(s3, u, p) != 0.0) == side
    d = rhs(s3, u, p)
    y = _rk4_end(x, h / 6.0, a, b, c, d)
    on = on and (not every or (contact(y, u, p) != 0.0) == side)
    return y, on


@njit(error_model="numpy")
def _across(x, u, p, h):
    """A sub-step of length ``h`` during which the contact force switches between zero and
    non-zero (module doc): the longest step whose stage points all stay on the starting side
    (bisection), a step of SWITCH_STEP·h across the switch, then the rest, which is checked the
    same way (a second switch, or a switch the short step did not reach, starts another round)."""
    rem = h
    for _ in range(SWITCH_ROUNDS):
        side = contact(x, u, p) != 0.0
        lo = 0.0
        hi = rem
        for _ in range(ONSET_BISECTIONS):
            mid = 0.5 * (lo + hi)
            if _rk4_on(x, u, p, mid, side, True)[1]:
                lo = mid
            else:
                hi = mid
        if lo > 0.0:
            x = _rk4(x, u, p, lo)
            rem -= lo
        tiny = min(rem, h * SWITCH_STEP)
        x = _rk4(x, u, p, tiny)
        rem -= tiny
        if rem <= 1e-15 * h:
            return x
        y, on = _rk4_on(x, u, p, rem, contact(x, u, p) != 0.0, True)
        if on:
            return y
    return _rk4(x, u, p, rem)


@njit(inline="always", error_model="numpy")  # numba-level inlining: 8 % faster
def _substep(x, u, p, h, side):
    """One sub-step from a state on contact side ``side``; returns the state and its side.

    Only the fourth stage's predicted end is tested here (one evaluation of the contact terms):
    the midpoints trail the path and the end is within O(h³) of the predicted end, so a switch
    shows there, except one so close to the end that the force it misses is negligible; the next
    sub-step then sees the new side and locates nothing more. Every stage point is tested while
    locating a switch (:func:`_across`).
    """
    y, on = _rk4_on(x, u, p, h, side, False)
    if on:
        return y, side
    y = _across(x, u, p, h)
    return y, contact(y, u, p) != 0.0


@njit(error_model="numpy")
def _advance(x, ua, ub, p, n_a, h_a, n_b, h_b):
    if not HAS_CONTACT:
        for _ in range(n_a):
            x = _rk4(x, ua, p, h_a)
        for _ in range(n_b):
            x = _rk4(x, ub, p, h_b)
        return x
    side = contact(x, ua, p) != 0.0
    for _ in range(n_a):
        x, side = _substep(x, ua, p, h_a, side)
    for _ in range(n_b):
        x, side = _substep(x, ub, p, h_b, side)
    return x


@njit(cache=True, nogil=True, error_model="numpy")
def step(x, ua, ub, p, n_a, h_a, n_b, h_b):
    """One sample from state ``x`` (N_STATE,): ``n_a`` sub-steps of ``h_a`` [s] with the command
    ``ua`` the actuator still sees, then ``n_b`` of ``h_b`` with ``ub``. Returns the next state."""
    y = _advance(_load(x), ua, ub, p, n_a, h_a, n_b, h_b)
    out = np.empty(N_STATE)
    for c in range(N_STATE):
        out[c] = y[c]
    return out


@njit(cache=True, nogil=True, error_model="numpy")
def replay(x0, duty, tau_before, whole, n_a, h_a, n_b, h_b, p, states, u_at, u_before):
    """Replay ``duty`` (N,) from ``x0`` (N_STATE,) with parameter vector ``p``.

    The actuator sees ``duty[j - whole - 1]`` on the first ``n_a`` sub-steps of sample j and
    ``duty[j - whole]`` on the other ``n_b`` (``tau_before`` before the first command). Fills
    ``states`` (N, N_STATE), the state at each sample instant, ``u_at`` (N,), the command the
    actuator sees there, and ``u_before`` (N,), the one it saw just before (they differ where a
    command arrives at the instant). Returns -1, or the first sample whose state is not finite (the
    rest is unset).
    """
    n = duty.size
    x = _load(x0)
    for j in range(n):
        ja = j - whole - 1
        jb = j - whole
        ua = duty[ja] if ja >= 0 else tau_before
        ub = duty[jb] if jb >= 0 else tau_before
        if not _finite(x):
            return j
        for c in range(N_STATE):
            states[j, c] = x[c]
        u_at[j] = ua if n_a > 0 else ub
        u_before[j] = ua
        x = _advance(x, ua, ub, p, n_a, h_a, n_b, h_b)
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
        derived = derived or c >= N_STATE
        current = current or c == CODE_I_A
    sig = (0.0, 0.0, 0.0, 0.0, 0.0)
    i_a = 0.0
    for j in range(u_at.size):
        if derived:
            sig = signals(_load(states[j]), u_at[j], p)
            i_a = sig[CODE_I_A - SIGNAL_OFFSET]
        if current and u_before[j] != u_at[j]:
            i_a = signals(_load(states[j]), u_before[j], p)[CODE_I_A - SIGNAL_OFFSET]
        for k in range(codes.size):
            c = codes[k]
            out[k, j] = states[j, c] if c < N_STATE else (i_a if c == CODE_I_A else sig[c - SIGNAL_OFFSET])


@njit(cache=True, nogil=True, error_model="numpy")
def replay_batch(x0, duty, tau_before, whole, n_a, h_a, n_b, h_b, p, codes, out, failed, start, stop):
    """:func:`replay` and :func:`outputs` for rows ``start`` to ``stop - 1`` of ``p`` (B, P) and
    ``x0`` (B, N_STATE), each with its own sub-step plan (``whole``, ``n_a``, ``h_a``, ``n_b``,
    ``h_b``: (B,)); ``out`` (B, C, N), ``failed`` (B,) as :func:`replay` returns. Releases the GIL,
    so threads can run disjoint row ranges at once (:meth:`CompiledPlant.replay_batch`)."""
    n = duty.size
    states = np.empty((n, N_STATE))
    u_at = np.empty(n)
    u_before = np.empty(n)
    for b in range(start, stop):
        failed[b] = replay(x0[b], duty, tau_before, whole[b], n_a[b], h_a[b], n_b[b], h_b[b], p[b], states,
                           u_at, u_before)
        if failed[b] < 0:
            outputs(states, u_at, u_before, p[b], codes, out[b])


@njit(cache=True, nogil=True, error_model="numpy")
def derivatives(x, u, p, out, drive):
    """Fill ``out`` (N, N_STATE) with the right-hand side dx/dt at the states ``x`` (N, N_STATE) and
    commands ``u`` (N,) (the command reaching the actuator), and ``drive`` (N,) with the drive
    quantity there (v_a or the ESC's set-point, of the command past the lag and the duty
    transforms: the second value of :func:`signals`)."""
    for j in range(x.shape[0]):
        xj = _load(x[j])
        d = rhs(xj, u[j], p)
        drive[j] = signals(xj, u[j], p)[1]
        for c in range(N_STATE):
            out[j, c] = d[c]


@njit(cache=True, nogil=True, error_model="numpy")
def jacobians(x, u, p):
    """Central-difference Jacobians ∂rhs/∂x (B, R, N_STATE, N_STATE) at the states ``x``
    (R, N_STATE) and commands ``u`` (R,) for each parameter row of ``p`` (B, P) (step
    1e-6·max(1, |x|))."""
    out = np.zeros((p.shape[0], x.shape[0], N_STATE, N_STATE))
    for b in range(p.shape[0]):
        for r in range(x.shape[0]):
            for c in range(N_STATE):
                h = 1e-6 * max(1.0, abs(x[r, c]))
                hi = x[r].copy()
                lo = x[r].copy()
                hi[c] += h
                lo[c] -= h
                fh = rhs(_load(hi), u[r], p[b])
                fl = rhs(_load(lo), u[r], p[b])
                for k in range(N_STATE):
                    out[b, r, k, c] = (fh[k] - fl[k]) / (2.0 * h)
    return out


@njit(inline="always", error_model="numpy")
def _rotor_rates(y, w, tf, u, p):
    """(dω₁/dt, dτ_f/dt) of :func:`rhs` at ``y`` (N_STATE,) with ω₁ = ``w`` and τ_f = ``tf``
    clipped to [0, 1] written into it, at the command ``u``."""
    y[OMEGA] = w
    y[TAU_F] = min(max(tf, 0.0), 1.0)
    d = rhs(_load(y), u, p)
    return d[OMEGA], d[TAU_F]


@njit(inline="always", error_model="numpy")
def _thrust_at(y, w, u, p):
    """The thrust [N] at the rotor speed ``w`` (:func:`signals`' last value; the other entries of
    ``y`` do not reach it)."""
    y[OMEGA] = w
    return signals(_load(y), u, p)[4]


@njit(cache=True, nogil=True, error_model="numpy")
def rotor_step(x, w, tf, u, h, p):
    """One RK4 step of length ``h`` [s] of the rotor speed ω₁ and the lagged duty τ_f alone, from
    ``w`` and ``tf``, the other entries of the state ``x`` (N_STATE,) held, at the command ``u``:
    the thrust predictor of a controller's observer
    (:class:`aeropend_control.observer.ThrustPredictor`), the same floating-point operations in
    the same order (τ_f clipped to [0, 1] at each stage). Returns (ω₁ at the end, clipped at 0; τ_f
    at the end; the mean thrust over the step [N] by Simpson's rule on ω₁ at the start, at the
    second stage's midpoint, clipped at 0, and at the end)."""
    y = x.copy()
    a_w, a_t = _rotor_rates(y, w, tf, u, p)
    b_w, b_t = _rotor_rates(y, w + 0.5 * h * a_w, tf + 0.5 * h * a_t, u, p)
    c_w, c_t = _rotor_rates(y, w + 0.5 * h * b_w, tf + 0.5 * h * b_t, u, p)
    d_w, d_t = _rotor_rates(y, w + h * c_w, tf + h * c_t, u, p)
    w_mid = max(w + 0.5 * h * b_w, 0.0)
    w_end = max(w + h * (a_w + 2.0 * b_w + 2.0 * c_w + d_w) / 6.0, 0.0)
    f = (_thrust_at(y, w, u, p) + 4.0 * _thrust_at(y, w_mid, u, p) + _thrust_at(y, w_end, u, p)) / 6.0
    return w_end, tf + h * (a_t + 2.0 * b_t + 2.0 * c_t + d_t) / 6.0, f
