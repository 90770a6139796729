"""Dense output of a heyoka run: ``sol(t)`` anywhere in the integrated interval."""

from __future__ import annotations

from fractions import Fraction

import numpy as np

from ..precision import Precision, data_bits, to_fraction, warn_if_coarse
from ..timegrid import span_loss, warn_span_loss


class DenseOutput:
    """``sol(t)`` of a heyoka run: its continuous outputs (one per chunk of steps), picklable. ``t0`` is the run's
    start (exact) and ``t0_native`` as the run held it: a time whose span t - t0 the run's format keeps to fewer
    bits than its own gives the grid's :class:`~lieseries.precision.PrecisionWarning`."""

    def __init__(self, c_outs, prec: Precision | None, t0=0, t0_native=0):
        self.c_outs = list(c_outs)
        self.prec = prec
        self.t0, self.t0_native = to_fraction(t0), to_fraction(t0_native)
        self.bounds = [tuple(sorted(float(b) for b in c.bounds)) for c in self.c_outs]

    def at_native(self, t):
        """The state at ``t`` (in the run's format) from the chunk that covers it, or the nearest one for a time a
        rounding outside them all (the last chunk read at t0's end was read far from its steps)."""
        tv = float(t)
        i = min(range(len(self.bounds)), key=lambda k: max(self.bounds[k][0] - tv, tv - self.bounds[k][1], 0.0))
        return np.array(self.c_outs[i](t), copy=True)

    def __call__(self, t):
        lo = min(b[0] for b in self.bounds)
        hi = max(b[1] for b in self.bounds)
        scalar = np.ndim(t) == 0
        ts = [t] if scalar else list(np.asarray(t, dtype=object).ravel())
        if self.prec is not None:  # the double 0.1 asked of a quad run: the state at 0.1000000000000000055...
            warn_if_coarse(data_bits(ts), self.prec.bits, "t")
        out, exact, held = [], [], []
        beside = bool(self.t0 or self.t0_native)  # (from t0 = 0 every time keeps its own relative precision)
        for tk in ts:
            tf = to_fraction(tk, "t")
            tv = float(tf)
            if not (lo - 1e-15 * max(1.0, abs(lo)) <= tv <= hi + 1e-15 * max(1.0, abs(hi))):
                raise ValueError(f"`t` = {tv} is outside the integrated interval [{lo}, {hi}]")
            tn = self.prec.time(tf)
            if beside:
                exact.append(tf)
                held.append(to_fraction(tn))
            out.append(self.at_native(tn))
        # (as for a grid: the run depends on t - t0, which times beside a large t0 keep to few bits; each time
        # relative to its own span t - t0, whatever else the call asks)
        if beside:
            worst = (Fraction(0), None)
            for k, (tf, tn) in enumerate(zip(exact, held)):
                loss = span_loss([tf], self.t0, [tn], self.t0_native)[0]
                if loss > worst[0]:
                    worst = (loss, k)
            warn_span_loss(worst, exact, self.t0, self.prec.bits, f"dense output reads {self.prec.name} times")
        return out[0] if scalar else np.stack(out)
