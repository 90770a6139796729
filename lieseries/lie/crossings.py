"""The user's events on the Lie engine's steps: every crossing of an event expression on a step's polynomial.

An event expression g along a step is g(P(tau)), tau in [0, h], P the step's polynomial. A fixed number of
samples misses crossings that come in pairs between two samples (sin(400 q) along a pendulum's step: 124 of 786
crossings found with `success`). Here g is first *resolved* on the step: sampled at Chebyshev-Lobatto points (9, 17,
33, 65: each set contains the one before) until the Chebyshev coefficients of its interpolant fall below
:data:`RESOLVED` of the largest; where 65 points do not resolve it, the step is sampled in halves, each resolved
alike (down to 2^-12 of the step; beyond, a pole or a function faster than that, the sign changes of the piece's
65 samples, counted and warned of). The interpolants' real roots (their colleague matrices) give brackets, each
checked for a sign change of g itself at the working precision and solved there. An extremum of an interpolant
within :data:`DIP` of zero is looked at on g itself (Newton's method on its central differences): a dip whose bottom
crosses zero is a pair of crossings however shallow (q = p0 sin t against q = 1 with p0 = 1 + 1e-20 at 30 digits:
two crossings 2.8e-10 apart, each to 1e-26); a tangency, no crossing."""

from __future__ import annotations

import numpy as np

from ..precision import export_mpf, mp_context
from ..precision import thread_mp as mp

__all__ = ["UserEvents", "RESOLVED", "MAX_POINTS", "MAX_HALVINGS", "DIP", "DIP_ITERATIONS"]

#: A step's event expression is resolved when its interpolant's last three Chebyshev coefficients are below this
#: fraction of its largest (the interpolant then follows g to about this fraction of g's size over the step).
RESOLVED = 2.0 ** -40
#: The most Chebyshev-Lobatto points a step's event expression is sampled at before the step is halved.
MAX_POINTS = 65
#: The most halvings of a step's pieces for its events: beyond, the piece's samples' sign changes (a pole such as
#: 1/M2 is no crossing, and no piece resolves it), and the run says so (``stats.extra["events_unresolved"]``).
MAX_HALVINGS = 12

#: An extremum of a resolved interpolant within this fraction of g's size over the piece is looked at on g itself
#: (:meth:`UserEvents._dip`): two crossings around a dip shallower than the interpolant's accuracy.
DIP = 2.0 ** -24
#: Newton iterations on such a dip.
DIP_ITERATIONS = 12

_COSINES: dict = {}  # M -> the DCT-I matrix of M Chebyshev-Lobatto points


def _chebyshev(values):
    """The Chebyshev coefficients of the interpolant of ``values`` (floats) at M Chebyshev-Lobatto points
    x_j = -cos(pi j / (M - 1)) of [-1, 1] (ascending)."""
    M = len(values)
    C = _COSINES.get(M)
    if C is None:
        j = np.arange(M)
        C = np.cos(np.pi * np.outer(j, j) / (M - 1)) * (2.0 / (M - 1))
        C[:, 0] /= 2
        C[:, -1] /= 2
        C[0, :] /= 2
        C[-1, :] /= 2
        _COSINES[M] = C
    # x_j = -cos(...) = cos(pi (M - 1 - j) / (M - 1)): the values in the order of cos(pi j / (M - 1))
    return C @ np.asarray(values, dtype=float)[::-1]


class UserEvents:
    """Crossings of the user's events on each step's polynomial (in time order), found by :meth:`step`; ``found`` per
    name (time, state), ``fired`` the message of a terminal event that stopped the run, ``unresolved`` per name the
    steps with a piece no samples resolved (:meth:`_pieces`)."""

    def __init__(self, user_events, ps, pars):
        from ..expr import compile_expressions

        self.events = user_events
        npars = len(ps.parameter_values)
        for i, (name, expr, _direction, _terminal) in enumerate(user_events):
            try:
                compile_expressions(ps.variables, [expr], npars)
            except (NotImplementedError, ValueError, TypeError) as exc:
                raise ValueError(
                    f"`events[{i}]` ({name!r}, {expr}) cannot be evaluated by lie_integrate: {exc}. Write it with "
                    "the supported functions (an absolute value |f| has the same crossings as f: give f)"
                ) from None
        self.prog = compile_expressions(ps.variables, [e[1] for e in user_events], npars)
        self.pars = pars
        self.found = {e[0]: [] for e in user_events}
        self.fired = None
        self.unresolved = {}

    def _g(self, at, tau):
        return self.prog.evaluate(at(tau), self.pars, mp.dps, mp_context())

    def step(self, at, t0, hs, sgn):
        """Record the crossings in (t0, t0 + hs] of the step whose polynomial ``at(tau)`` evaluates, up to the
        first terminal one (the non-terminal crossings at its very time included); its time, or None."""
        pieces = self._pieces(at, mp.mpf(0), hs, 0)
        hits = []
        for i, (name, _expr, direction, terminal) in enumerate(self.events):
            for lo, hi, ga, gb in self._brackets(at, i, pieces, hs):
                if not ((ga < 0 < gb) or (gb < 0 < ga) or (gb == 0 and ga != 0)):
                    continue  # (a zero at tau = 0 was the previous step's crossing)
                rising = (gb > ga) if sgn > 0 else (gb < ga)
                if direction and (rising != (direction > 0)):
                    continue
                if gb == 0:
                    tau = hi
                else:
                    tau = self._solve(at, i, lo, hi, ga, gb)
                    if tau is None:
                        continue  # a sign change through a pole (1/M2), not a zero
                hits.append((abs(tau), t0 + tau, name, terminal, tau))
        hits.sort(key=lambda h: h[0])
        stop = None
        for key, t_hit, name, terminal, tau in hits:
            # after the stop, not recorded; at the stop's own time (within 2^(-3 prec / 4) of the step, where
            # the roots of two expressions crossing together fall by rounding, as in heyoka runs) recorded
            if stop is not None and (terminal or key > stop[0] + abs(hs) * mp.ldexp(1, -3 * mp.prec // 4)):
                continue
            self.found[name].append((t_hit, at(tau)))
            if terminal and stop is None:
                self.fired = f"the event {name!r} fired"
                stop = (key, t_hit)
        return None if stop is None else stop[1]

    def _pieces(self, at, lo, hi, depth):
        """The pieces of [lo, hi] on which every event is resolved (halves, down to :data:`MAX_HALVINGS`): per
        piece (lo, hi, its samples' taus, their values, each event's candidate roots in tau, or None where it is
        not resolved even there: a pole, or faster than any piece, counted in :attr:`unresolved`)."""
        taus, rows, roots = self._sample(at, lo, hi)
        if all(r is not None for r in roots) or depth == MAX_HALVINGS:
            if depth == MAX_HALVINGS:
                for (name, *_), r in zip(self.events, roots):
                    if r is None:
                        self.unresolved[name] = self.unresolved.get(name, 0) + 1
            return [(lo, hi, taus, rows, [None if r is None else tuple([lo + (hi - lo) * (x + 1) / 2 for x in xs]
                                                                       for xs in r) for r in roots])]
        mid = (lo + hi) / 2
        return self._pieces(at, lo, mid, depth + 1) + self._pieces(at, mid, hi, depth + 1)

    def _sample(self, at, lo, hi):
        """(taus, values, roots) on [lo, hi]: the Chebyshev-Lobatto samples (up to :data:`MAX_POINTS`, until every
        event is resolved) and each event's candidate roots x in [-1, 1], None for one not resolved."""
        n = len(self.events)
        vals = {}
        roots = [None] * n
        M = 9
        while True:
            taus = [lo + (hi - lo) * (1 - mp.cos(mp.pi * j / (M - 1))) / 2 for j in range(M)]
            taus[0], taus[-1] = lo, hi
            stride = (MAX_POINTS - 1) // (M - 1)  # (the points of M are every stride-th of MAX_POINTS's)
            for j in range(M):
                if j * stride not in vals:
                    vals[j * stride] = self._g(at, taus[j])
            rows = [vals[j * stride] for j in range(M)]
            for i in range(n):
                if roots[i] is not None:
                    continue
                col = [r[i] for r in rows]
                big = max(abs(v) for v in col)
                if not big:
                    roots[i] = ([], [])
                    continue
                c = _chebyshev([float(v / big) for v in col])
                if not np.isfinite(c).all():
                    raise ValueError("an event expression is not finite in the step")
                top = float(np.max(np.abs(c)))
                if float(np.max(np.abs(c[-3:]))) <= RESOLVED * top:
                    roots[i] = (_roots(c, RESOLVED * top), _dips(c, RESOLVED * top))
            if all(r is not None for r in roots) or M == MAX_POINTS:
                return taus, rows, roots
            M = 2 * M - 1

    def _brackets(self, at, i, pieces, hs):
        """Intervals (lo, hi, g(lo), g(hi)) of the step around each candidate crossing of event ``i``: the roots
        of its interpolants and its samples' sign changes (between two samples of opposite signs, at a sample that
        is zero), split at the midpoints between consecutive candidates, where g is evaluated, and at the bottom
        of each shallow dip that crossed zero (:meth:`_dip`)."""
        cand, dips = [], []
        for lo, hi, taus, rows, roots in pieces:
            col = [r[i] for r in rows]
            found, low = roots[i] if roots[i] is not None else ((), ())
            cand.extend(found)
            for tau in low:  # (the side g comes from: its sample nearest to the dip)
                near = min(range(len(taus)), key=lambda j: abs(taus[j] - tau))
                dips.append(self._dip(at, i, tau, lo, hi, col[near] > 0) if col[near] else None)
            for a in range(len(col) - 1):
                if (col[a] < 0 < col[a + 1]) or (col[a + 1] < 0 < col[a]):
                    cand.append((taus[a] + taus[a + 1]) / 2)
                elif col[a + 1] == 0 and col[a] != 0:
                    cand.append(taus[a + 1])
        dips = [d for d in dips if d is not None]
        if not cand and not dips:
            return []
        cand.sort(key=abs)
        first, last = pieces[0][3][0][i], pieces[-1][3][-1][i]  # g at tau = 0 and at hs (samples)
        ends = [(mp.mpf(0), first)]
        for a, b in zip(cand, cand[1:]):
            if a != b:
                m = (a + b) / 2
                ends.append((m, self._g(at, m)[i]))
        ends.append((hs, last))
        # a dip of g that the interpolants cannot tell from a tangency, whose bottom g itself shows across zero:
        # a pair of crossings, one on either side of it
        ends = sorted(ends + dips, key=lambda e: abs(e[0]))
        return [(lo, hi, ga, gb) for (lo, ga), (hi, gb) in zip(ends, ends[1:]) if lo != hi]

    def _dip(self, at, i, tau, lo, hi, positive):
        """(tau_m, g(tau_m)) at the bottom of a dip of event ``i`` towards zero near ``tau`` (an extremum of its
        interpolant on the piece [lo, hi] within :data:`DIP` of zero; g is ``positive`` or negative around it),
        found on g itself by Newton's method on its central differences, when g there has crossed zero: a pair of
        crossings, one on either side; else None."""
        sgn = 1 if positive else -1
        g0 = self._g(at, tau)[i]
        d = (hi - lo) * mp.mpf(2) ** (-(mp.prec // 3))
        for _ in range(DIP_ITERATIONS):
            if sgn * g0 <= 0:
                return (tau, g0) if g0 else None
            gm, gp = self._g(at, tau - d)[i], self._g(at, tau + d)[i]
            curv = sgn * (gp - 2 * g0 + gm)
            if curv <= 0:  # not a dip towards zero here
                return None
            step = d * (gp - gm) / (2 * (gp - 2 * g0 + gm))
            tau -= step
            if not (min(lo, hi) <= tau <= max(lo, hi)):
                return None
            g0 = self._g(at, tau)[i]
            if abs(step) <= d:
                break
        return (tau, g0) if sgn * g0 < 0 else None

    def _solve(self, at, i, lo, hi, glo, ghi):
        """The zero of event ``i`` between ``lo`` and ``hi`` (opposite signs ``glo``, ``ghi``) on the step's
        polynomial: Anderson's method, bisection when it fails or leaves the bracket; None when the sign changes
        through a pole (the function grows instead of vanishing)."""
        def g(x):
            try:
                return self._g(at, x)[i]
            except ZeroDivisionError:  # on a pole
                return mp.inf

        tau = None
        try:
            tau = mp.findroot(g, (lo, hi), solver="anderson")
        except (ValueError, ZeroDivisionError):
            pass
        if tau is None or not (min(lo, hi) <= tau <= max(lo, hi)):
            a, b, ga = lo, hi, glo
            for _ in range(4 * mp.prec):
                mid = (a + b) / 2
                if mid == a or mid == b:
                    break
                gm = g(mid)
                if gm == 0:
                    a = b = mid
                    break
                if (gm < 0) == (ga < 0):
                    a, ga = mid, gm
                else:
                    b = mid
            tau = b
        if abs(g(tau)) > max(abs(glo), abs(ghi)):
            return None
        return tau

    def records(self, prec, n):
        """The crossings found, rounded to ``prec`` bits."""
        return {name: {"t": np.array([export_mpf(t, prec) for t, _ in hits], dtype=object),
                       "y": (np.stack([export_mpf(np.array(y, dtype=object), prec) for _, y in hits]) if hits
                             else np.empty((0, n), dtype=object))}
                for name, hits in self.found.items()}


def _trimmed(c, floor):
    """The Chebyshev series ``c`` without its top coefficients of at most ``floor``."""
    k = len(c)
    while k > 1 and abs(c[k - 1]) <= floor:
        k -= 1
    return c[:k]


def _dips(c, floor):
    """The extrema in (-1, 1) of the Chebyshev series ``c`` (normalised to g's size; its coefficients below ``floor``
    at the top dropped) within :data:`DIP` of zero, as floats."""
    c = _trimmed(c, floor)
    if len(c) <= 2:
        return []
    cheb = np.polynomial.chebyshev
    return [x for x in _roots(cheb.chebder(c), 0.0) if -1 < x < 1 and abs(cheb.chebval(x, c)) <= DIP]


def _roots(c, floor):
    """The real roots in [-1, 1] of the Chebyshev series ``c`` (its coefficients below ``floor`` at the top
    dropped), as floats; none for a constant."""
    c = _trimmed(c, floor)
    if len(c) <= 1:
        return []
    try:
        r = np.polynomial.chebyshev.chebroots(c)
    except np.linalg.LinAlgError:  # pragma: no cover - the samples' sign changes still give brackets
        return []
    out = []
    for z in np.atleast_1d(r):
        if abs(z.imag) <= 1e-6 and -1 - 1e-9 <= z.real <= 1 + 1e-9:
            out.append(min(1.0, max(-1.0, float(z.real))))
    return out
