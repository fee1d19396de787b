"""Interacting multiple model filter on converted measurements, vectorised over rows."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from .. import defaults
from . import kalman, models, pda, timing, turn
from .batch import einsum
from .filters import Convert, Result, Rows, moments, predict
from .ucm import CMKFConversion

Mode = tuple[str, str, float, float]  # name, kind ("cv", "ca", "ct", "turn"), q, omega (rad/s)
ACCELERATING = ("ca", "turn")  # the kinds whose acceleration is estimated


@dataclass(frozen=True)
class ModeSet:
    """The service's IMM design: a quiet CV mode (white acceleration `quiet_q`, m/s^2),
    a nominal CV mode (`q`), a CA mode (white jerk `ca_q`, m/s^3) and manoeuvre modes
    `manoeuvre` (kind "cv", "ca" or "turn" and its white noise, m/s^2 or m/s^3, or "ct",
    its noise and its turn rate in deg/s), plus, with `turn_deg` > 0,
    coordinated turns at +- `turn_deg` deg/s with `ct_q` x q. Quiet <-> nominal <-> CA
    (and turns) are chained: the quiet and nominal modes are left for each
    other and the CA mode in `sojourn` s on average, the CA (and turn) modes in
    `manoeuvre_sojourn` s. Besides, every one of those modes enters the manoeuvre modes
    at the rate 1 / `onset` (shared evenly; a "ct" one `ct_entry` times as often), and
    a manoeuvre mode is left in `turn_sojourn` s (a "ct" one in `ct_sojourn` s), half
    for the nominal and quiet modes (`exit_quiet` of it for the quiet one), the rest
    evenly for the CA and the other manoeuvre modes. A new track
    starts with the probabilities `initial` (quiet, nominal, CA and turns together,
    manoeuvre modes together). docs/accuracy.md gives the reasons."""

    q: float = defaults.Q_CV
    quiet_q: float = defaults.IMM_QUIET_Q
    ca_q: float = defaults.IMM_CA_Q
    sojourn: float = defaults.IMM_SOJOURN
    manoeuvre_sojourn: float = defaults.IMM_MANOEUVRE_SOJOURN
    initial: tuple[float, ...] = defaults.IMM_INITIAL
    ct_q: float = defaults.IMM_CT_Q
    turn_deg: float = defaults.IMM_TURN_DEG
    manoeuvre: tuple[tuple, ...] = defaults.IMM_MANOEUVRE
    onset: float = defaults.IMM_ONSET
    turn_sojourn: float = defaults.IMM_TURN_SOJOURN
    ct_sojourn: float = defaults.IMM_CT_SOJOURN
    ct_entry: float = defaults.IMM_CT_ENTRY
    exit_quiet: float = defaults.IMM_EXIT_QUIET
    dv_cap: float = defaults.IMM_WIDE_DV

    def imm(self, kind: type[IMM] | None = None) -> IMM:
        """The IMM of this design (`kind`: the class built, `IMM` by default; the
        catalogue builds `imm_jit.CompiledIMM`)."""
        modes: list[Mode] = [("quiet", "cv", self.quiet_q, 0.0), ("cv", "cv", self.q, 0.0),
                             ("ca", "ca", self.ca_q, 0.0)]
        if self.turn_deg > 0:
            w = float(np.radians(self.turn_deg))
            modes += [("ct+", "ct", self.ct_q * self.q, w), ("ct-", "ct", self.ct_q * self.q, -w)]
        b = len(modes)  # the chained modes; the manoeuvre modes follow
        modes += [(f"{m[0]}{m[1]:g}{'' if len(m) < 3 else f'@{m[2]:g}'}", m[0], m[1],
                   float(np.radians(m[2])) if len(m) > 2 else 0.0) for m in self.manoeuvre]
        m, k = len(modes), len(self.manoeuvre)
        rate = np.zeros((m, m))  # rate[i, j]: per second from mode i to mode j
        rate[0, 1] = 1.0 / self.sojourn
        rate[1, [0, *range(2, b)]] = 1.0 / self.sojourn / (b - 1)
        rate[2:b, 1] = 1.0 / self.manoeuvre_sojourn
        if k:
            for j in range(b, m):  # the turns at a known rate ct_entry times as often
                rate[:b, j] = (self.ct_entry if modes[j][1] == "ct" else 1.0) / self.onset / k
            for i in range(b, m):
                rest = [2, *[j for j in range(b, m) if j != i]]
                tau = self.ct_sojourn if modes[i][1] == "ct" else self.turn_sojourn
                rate[i, 0] = self.exit_quiet / tau
                rate[i, 1] = (0.5 - self.exit_quiet) / tau
                rate[i, rest] += 0.5 / tau / len(rest)
        total = rate.sum(1)
        quiet, nominal, manoeuvre, *turns = (*self.initial, 0.0)[:4]
        initial = (quiet, nominal, *[manoeuvre / (b - 2)] * (b - 2), *[turns[0] / k] * k) \
            if k else (quiet, nominal, *[(manoeuvre + turns[0]) / (b - 2)] * (b - 2))
        return (kind or IMM)(tuple(modes), tuple((1.0 / total).tolist()),
                             tuple(map(tuple, (rate / total[:, None]).tolist())), initial,
                             dv_cap=self.dv_cap)


@dataclass(frozen=True)
class IMM:
    """Interacting multiple model filter (Blom & Bar-Shalom 1988; Bar-Shalom, Li &
    Kirubarajan 2001, sec. 11.6.6) on converted measurements, vectorised over rows.

    `modes` are (name, kind, q, omega) in a padded order-3 state: CV and CT modes hold
    the acceleration at zero. Mode switching is a continuous-time Markov chain: mode i
    is left at the rate 1 / sojourn_i (staying probability exp(-dt / sojourn_i) over a
    step dt, so irregular scan intervals are handled) for the other modes in proportion
    to `leave` (a row per mode; None: evenly). `initial`: the mode probabilities of a new
    track (None: evenly).

    Mixing into a mode with an acceleration (CA) takes, for a mode without one, that
    mode's own acceleration estimate and covariance in place of the zero padding (the
    unbiased mixing of Granström, Willett & Bar-Shalom, IEEE TAES 51(4), 2015), so
    quiet modes do not pull the manoeuvre mode's acceleration toward zero. The converted
    measurement's covariance R is averaged over the mixture of the modes' predictions and
    shared by the modes (`mode_conversion`: each over its own prediction instead).
    This is the textbook form, the reference of the compiled one (`imm_jit.CompiledIMM`,
    which the catalogue builds).
    """

    modes: Sequence[Mode]
    sojourn: float | Sequence[float] = 200.0
    leave: Sequence[Sequence[float]] | None = None
    initial: Sequence[float] | None = None
    mode_conversion: bool = defaults.IMM_MODE_R  # True: each mode's own R
    gate_wide: float = defaults.IMM_GATE_WIDE  # association's prior of the widest mode
    turn_cap: float = defaults.IMM_TURN_CAP  # rad/s: a "turn" mode's rate at most
    dv_cap: float = defaults.IMM_WIDE_DV  # m/s: a CV mode's q |dt| at most (0: unbounded)
    order: int = 3

    @property
    def fields(self) -> dict[str, tuple]:
        """Per-row arrays kept in the track store: each mode's state, covariance and
        probability."""
        m = len(self.modes)
        return {"mode_x": ("n", m), "mode_p": ("nn", m), "mode_prob": ("", m)}

    def initiate(self, arrays: Rows, rows: np.ndarray) -> None:
        arrays.mode_x[rows] = arrays.x[rows, None]
        arrays.mode_p[rows] = arrays.p[rows, None]
        m = len(self.modes)
        mu = np.full(m, 1.0 / m) if self.initial is None else np.asarray(self.initial, float)
        arrays.mode_prob[rows] = mu / mu.sum()

    def transition(self, dt: np.ndarray) -> np.ndarray:
        """pi[n, i, j] = P(mode j at the next update | mode i now) over steps dt (N,)."""
        m = len(self.modes)
        tau = np.broadcast_to(np.asarray(self.sojourn, dtype=float), (m,))
        stay = np.exp(-np.abs(np.asarray(dt, dtype=float))[:, None] / tau)  # (N, m)
        pi = (1 - stay)[:, :, None] * self.destinations()
        idx = np.arange(m)
        pi[:, idx, idx] = stay
        return pi

    def destinations(self) -> np.ndarray:
        """Where a mode left goes (M, M): `leave` normalised per row, never itself (None:
        evenly); as the compiled kernel reads it too (`imm_jit.design`)."""
        m = len(self.modes)
        dest = np.ones((m, m)) if self.leave is None else np.array(self.leave, dtype=float)
        dest[np.arange(m), np.arange(m)] = 0.0
        dest /= np.maximum(dest.sum(1, keepdims=True), 1e-300)
        return dest

    def mix(self, mx: np.ndarray, mp: np.ndarray, mu: np.ndarray, pi: np.ndarray, dim: int
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Predicted mode probabilities c (N, M) and the mixed initial conditions
        x0 (N, M, n), P0 (N, M, n, n) of every mode (`mix_moments`), a mode with an
        acceleration mixing the others padded with its own (unbiased mixing)."""
        n_rows, m, n = mx.shape
        c, w, x0, p0 = mix_moments(mx, mp, mu, pi)
        acc = slice(2 * dim, 3 * dim)
        has = np.array([kind in ACCELERATING for _, kind, _, _ in self.modes])
        if has.any() and not has.all():
            for j in np.flatnonzero(has).tolist():  # pad the others with j's acceleration
                xs, ps = mx.copy(), mp.copy()
                xs[:, ~has, acc] = mx[:, j, None, acc]
                ps[:, ~has, acc, :] = 0.0
                ps[:, ~has, :, acc] = 0.0
                ps[:, ~has, acc, acc] = mp[:, j, None, acc, acc]
                wj = w[:, None, :, j]  # (N, 1, i)
                x0[:, j] = (wj @ xs)[:, 0]
                dj = xs - x0[:, j, None]
                p0[:, j] = (wj @ ps.reshape(n_rows, m, n * n)).reshape(n_rows, n, n) \
                    + (w[:, :, j, None] * dj).transpose(0, 2, 1) @ dj
        return c, x0, p0

    def predict_mode(self, j: int, dt: np.ndarray, x0: np.ndarray, p0: np.ndarray,
                     dim: int) -> tuple[np.ndarray, np.ndarray]:
        """Mode j's prediction over dt of its mixed states x0 (N, n), P0 (N, n, n): a
        "turn" mode's rate is each state's own (`turn.turn_model`, an EKF); a CV mode's
        white acceleration at most `dv_cap` / |dt|."""
        _, kind, q, omega = self.modes[j]
        if kind == "cv" and self.dv_cap > 0:
            q = cv_noise(q, self.dv_cap, dt)
        if kind != "turn":
            return predict(x0, p0, *models.motion(kind, dt, self.order, dim, q, omega))
        f, qm, jac = turn.turn_model(x0, dt, dim, q, self.turn_cap)
        xp = (f @ x0[:, :, None])[:, :, 0]
        return xp, kalman.symmetrise(jac @ p0 @ jac.transpose(0, 2, 1) + qm)

    def predicted(self, arrays: Rows, rows: np.ndarray, dt: np.ndarray
                  ) -> tuple[np.ndarray, list[tuple[np.ndarray, np.ndarray]]]:
        """The rows' predicted mode probabilities c (N, M) and each mode's prediction
        over dt from its mixed initial conditions: (x (N, n), P (N, n, n)) per mode."""
        mx, mp, mu = arrays.mode_x[rows], arrays.mode_p[rows], arrays.mode_prob[rows]
        c, x0, p0 = self.mix(mx, mp, mu, self.transition(dt), arrays.dim)
        return c, [self.predict_mode(j, dt, x0[:, j], p0[:, j], arrays.dim)
                   for j in range(len(self.modes))]

    def update(self, arrays: Rows, rows: np.ndarray, dt: np.ndarray, convert: Convert) -> Result:
        c, preds = self.predicted(arrays, rows, dt)

        def parts(xp: np.ndarray, pp: np.ndarray) -> tuple:
            """z, R and the time's noise T with its rows (`CMKFConversion.parts`)."""
            if isinstance(convert, CMKFConversion):
                return convert.parts(xp, pp)
            return (*convert(xp, pp)[:2], None, None)

        if not self.mode_conversion:
            z, r, term, some = parts(*moments(np.stack([x for x, _ in preds], 1),
                                              np.stack([p for _, p in preds], 1), c))
        outs, rs = [], []
        for xp, pp in preds:
            if self.mode_conversion:
                z, r, term, some = parts(xp, pp)  # R averaged over this mode's prediction
            if term is None:
                xm, pm, _, okm, llm = kalman.update_full(xp, pp, z, r)
            else:  # the time's noise a mixture: each mode's likelihood the mixture's
                xm, pm, okm, llm = timing.mixture_update(kalman.update_full, xp, pp, z, r,
                                                         term, some)
            outs.append((xp, pp, xm, pm, okm, llm))
            rs.append(r if term is None else r + term)
        xu = np.stack([o[2] for o in outs], 1)
        pu = np.stack([o[3] for o in outs], 1)
        loglik = np.stack([o[5] for o in outs], 1)
        ok = np.all([o[4] for o in outs], 0)
        x, p, ok = _posterior(arrays, rows, c, loglik, xu, pu, ok)
        # NIS of the mixture's prediction, with R averaged over it: sum_j c_j R_j
        xbar, pbar = moments(np.stack([o[0] for o in outs], 1),
                             np.stack([o[1] for o in outs], 1), c)
        rbar = einsum("nj,jnab->nab", c, np.stack(rs))
        _, _, nis, _ = kalman.update(xbar, pbar, z, rbar)
        return x, p, nis, ok

    def update_pda(self, arrays: Rows, rows: np.ndarray, dt: np.ndarray, weighted: Any
                   ) -> Result:
        """`update` by weighted detections (`tracking.hypotheses.WeightedUpdate`: JPDA's
        or PDA's): each mode updated by the PDA of its own prediction and weighed by its
        own likelihood of the scan (`pda.pda_update`, the IMM-PDAF), so that a far
        detection of small probability neither moves every mode to the widest one nor
        gives the quiet ones the widest one's spread."""
        w = weighted
        c, preds = self.predicted(arrays, rows, dt)
        xp, pp = np.stack([x for x, _ in preds], 1), np.stack([p for _, p in preds], 1)
        t_count, m, n = xp.shape
        ti = (w.ti[:, None] * m + np.arange(m)).ravel()  # pair k, mode j: row k * m + j
        k = np.repeat(np.arange(len(w.ti)), m)
        xu, pu, loglam, ok = pda.pda_update(xp.reshape(-1, n), pp.reshape(-1, n, n), ti,
                                            w.pz[k], w.pr[k], w.beta[k], w.pd, w.lam)
        xu, pu = xu.reshape(t_count, m, n), pu.reshape(t_count, m, n, n)
        x, p, ok = _posterior(arrays, rows, c, loglam.reshape(t_count, m), xu, pu,
                              ok.reshape(t_count, m).all(1))
        xbar, pbar = moments(xp, pp, c)  # NIS: the mixture's prediction, the equivalent z
        _, _, nis, _ = kalman.update(xbar, pbar, w.z, w.r)
        return x, p, nis, ok

    def gate_prediction(self, arrays: Any, rows: np.ndarray, t: float
                        ) -> tuple[np.ndarray, np.ndarray, Callable]:
        """What the tracks `rows` are gated with at `t` (`tracking.gating.gate`).

        The gate: the position mean (N, d) of the IMM's predicted mixture (mixing, then
        each mode's own model and noise, weighted by the predicted mode probabilities
        c) and the position rows (N, d, n) of the second moment about that mean of its
        widest mode (largest predicted position variance), so that a manoeuvre one of
        the modes allows stays in the gate before that mode's probability has grown:
        gating with the model of largest covariance (Blackman & Popoli 1999, sec. 4.5).
        The likelihood of a pair (the returned function, of the log-likelihoods under
        the gate, the pairs' tracks, innovations and R): the two-component mixture
        (1 - w) N(nu; S_mix) + w N(nu; S_wide), S_mix from the mixture's moments, with
        w = max(c_wide, `gate_wide`): the association gives a manoeuvre it cannot see
        yet the prior `gate_wide`, so that clutter far out in a wide gate (a track
        coasting through missed scans) is not taken for the aircraft."""
        mean, cross, narrow, c_wide = self.gate_moments(arrays, rows, t - arrays.t[rows])
        w = np.maximum(c_wide, self.gate_wide)

        def likelihood(loglik: np.ndarray, ti: np.ndarray, nu: np.ndarray, r: np.ndarray
                       ) -> np.ndarray:
            return self.pair_likelihood(loglik, ti, nu, r, narrow, w)

        return mean, cross, likelihood

    def pair_likelihood(self, loglik: np.ndarray, ti: np.ndarray, nu: np.ndarray,
                        r: np.ndarray, narrow: np.ndarray, w: np.ndarray) -> np.ndarray:
        """`gate_prediction`'s pair log-likelihood: log((1 - w) N(nu; narrow[ti] + r)
        + w exp(loglik)), w and narrow per track, loglik the widest mode's."""
        d = nu.shape[1]
        s = narrow[ti] + r
        sign, logdet = np.linalg.slogdet(s)
        d2 = einsum("ka,ka->k", nu, np.linalg.solve(s, nu[:, :, None])[:, :, 0])
        ll = np.where(sign > 0, -0.5 * (d2 + logdet + d * np.log(2 * np.pi)), -np.inf)
        with np.errstate(divide="ignore"):  # w = 1: the widest mode alone
            return np.logaddexp(np.log1p(-w[ti]) + ll, np.log(w[ti]) + loglik)

    def gate_moments(self, arrays: Rows, rows: np.ndarray, dt: np.ndarray
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """`gate_prediction`'s moments of the predicted mixture over dt: its position mean
        (N, d), the widest mode's position rows of the second moment about it (N, d, n),
        the mixture's position covariance (N, d, d) and the widest mode's predicted
        probability (N,)."""
        d = arrays.dim
        c, preds = self.predicted(arrays, rows, dt)
        xs, ps = [x for x, _ in preds], [p for _, p in preds]
        xs_, ps_ = np.stack(xs, 1), np.stack(ps, 1)  # (N, M, n), (N, M, n, n)
        mean, cov = moments(xs_, ps_, c)
        wide = np.trace(ps_[:, :, :d, :d], axis1=2, axis2=3).argmax(1)
        k = np.arange(len(rows))
        dev = xs_[k, wide] - mean
        cross = ps_[k, wide, :d] + dev[:, :d, None] * dev[:, None, :]
        return mean[:, :d], cross, cov[:, :d, :d], c[k, wide]

    def inflate(self, arrays: Rows, rows: np.ndarray, dp: np.ndarray) -> None:
        """The tracker added dp to the combined covariances of rows (the spread of a PDA
        update): every mode's covariance takes it too."""
        arrays.mode_p[rows] += dp[:, None]

    def labels(self, arrays: Rows, rows: np.ndarray) -> ModeProbabilities:
        return ModeProbabilities([name for name, *_ in self.modes], arrays.mode_prob[rows])


def mix_moments(mx: np.ndarray, mp: np.ndarray, mu: np.ndarray, pi: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The IMM's mixing (Bar-Shalom, Li & Kirubarajan 2001, sec. 11.6.6): predicted mode
    probabilities c (N, M), mixing weights w (N, i, j) = mu_{i|j}, and the mixed initial
    conditions x0_j = sum_i w_ij x_i, P0_j = sum_i w_ij (P_i + (x_i - x0_j)(x_i - x0_j)'),
    as batched matrix products."""
    n_rows, m, n = mx.shape
    c = einsum("nij,ni->nj", pi, mu)  # predicted mode probabilities
    w = pi * mu[:, :, None] / np.maximum(c[:, None, :], 1e-300)  # mixing mu_{i|j}
    wt = w.transpose(0, 2, 1)  # (N, j, i)
    x0 = wt @ mx
    d = mx[:, :, None] - x0[:, None]  # (N, i, j, n): x_i about mode j's mix
    p0 = (wt @ mp.reshape(n_rows, m, n * n)).reshape(n_rows, m, n, n) \
        + (w[..., None] * d).transpose(0, 2, 3, 1) @ d.transpose(0, 2, 1, 3)
    return c, w, x0, p0


def cv_noise(q: float, dv_cap: float, dt: np.ndarray) -> np.ndarray:
    """A CV mode's white acceleration per row of dt: q, but at most `dv_cap` / |dt|, so
    that the velocity it lets change over a step (q |dt|, one sigma per axis) stays within
    what an aircraft can do whatever the step (docs/accuracy.md, "Beyond 5 s")."""
    at = np.abs(np.asarray(dt, dtype=float))
    return np.minimum(q, dv_cap / np.maximum(at, 1e-300))


def _posterior(arrays: Rows, rows: np.ndarray, c: np.ndarray, loglik: np.ndarray,
               xu: np.ndarray, pu: np.ndarray, ok: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The modes' updates (xu, pu) and likelihoods of rows put in the store with their
    new probabilities (predicted c times the likelihood); the combined state, covariance
    and the mask of the rows updated (finite)."""
    logw = np.log(np.maximum(c, 1e-300)) + loglik
    with np.errstate(invalid="ignore"):  # a row with no finite mode: masked by ok
        logw -= logw.max(1, keepdims=True)
        mu_new = np.exp(logw)
        mu_new /= mu_new.sum(1, keepdims=True)
    ok &= np.isfinite(mu_new).all(1)
    good = rows[ok]
    arrays.mode_x[good], arrays.mode_p[good] = xu[ok], pu[ok]
    arrays.mode_prob[good] = mu_new[ok]
    x, p = moments(xu, pu, np.where(np.isfinite(mu_new), mu_new, 0.0))
    return x, p, ok


class ModeProbabilities(Sequence):
    """Tracks' mode probabilities `mu` (N, M) under the mode names: track i's as a map
    {name: probability} (`self[i]`, the `model` of its `tracks/` body), the array for
    encoders that write all the tracks at once."""

    def __init__(self, names: list[str], mu: np.ndarray) -> None:
        self.names, self.mu = names, mu

    def __len__(self) -> int:
        return len(self.mu)

    def __getitem__(self, i: Any) -> Any:
        if isinstance(i, slice):
            return ModeProbabilities(self.names, self.mu[i])
        return dict(zip(self.names, self.mu[i].tolist(), strict=True))

    def take(self, rows: Sequence[int] | np.ndarray) -> ModeProbabilities:
        """The tracks at `rows`, in that order."""
        return ModeProbabilities(self.names, self.mu[np.asarray(rows, dtype=int)])
