"""A model as a plug-in, in one file: the harmonic oscillator H = (p^2 + w^2 q^2) / 2 on the canonical plane.

It registers the scene kind ``harmonic`` (field ``omega``), the initial data ``[initial] q, p`` and its closed form
q(t) = q0 cos(wt) + (p0 / w) sin(wt), p(t) = p0 cos(wt) - w q0 sin(wt), which becomes the reference of its runs.
"""

from fractions import Fraction

import heyoka as hy
import numpy as np

import lieseries as ls
from lieseries import fields as F
from lieseries.models.base import Model, make_state, state_fractions
from lieseries.models.kinds import InitialFamily, ModelKind, register_initial_family, register_model_kind
from lieseries.precision import thread_mp as mp
from lieseries.precision import to_fraction
from lieseries.studies.reference import ClosedForm, register_closed_form


class Harmonic(Model):
    closed_form = "harmonic"

    def __init__(self, omega=1):
        self.omega = to_fraction(omega, "omega")
        if self.omega <= 0:
            raise ValueError(f"`omega` must be positive; got {float(self.omega)}")
        q, p = hy.make_vars("q", "p")
        self.poisson = ls.PoissonSystem([q, p], [[0, 1], [-1, 0]], (p**2 + hy.par[0] * q**2) / 2,
                                        parameters={"omega2": self.omega**2}, name="harmonic oscillator")

    def initial_state(self, q, p, precision=None):
        return make_state([to_fraction(q, "q"), to_fraction(p, "p")], precision, inputs={"q": q, "p": p})

    def invariants(self, y):
        """{"energy": H} as mpf (40 digits) of a state, or a list of them for one state per row."""
        one = np.ndim(y) == 1
        rows = [state_fractions(r, 2, "y") for r in ([y] if one else list(y))]
        with mp.workdps(40):
            energy = [(p * p + self.omega**2 * q * q) / 2 for q, p in rows]
            energy = [mp.mpf(e.numerator) / e.denominator for e in energy]
        return {"energy": energy[0] if one else energy}


def _closed_form(model, fr, t, dps):
    q0, p0 = fr
    with mp.workdps(dps + 10):
        w = mp.mpf(model.omega.numerator) / model.omega.denominator
        wt = w * mp.mpf(Fraction(t).numerator) / Fraction(t).denominator
        q0, p0 = mp.mpf(q0.numerator) / q0.denominator, mp.mpf(p0.numerator) / p0.denominator
        q = q0 * mp.cos(wt) + p0 / w * mp.sin(wt)
        p = p0 * mp.cos(wt) - w * q0 * mp.sin(wt)
    with mp.workdps(dps):
        return [+q, +p]


register_closed_form(ClosedForm("harmonic", "closed form (cos, sin)", _closed_form))

register_initial_family(InitialFamily(
    "oscillator",
    fields={"q": (F.number, F.REQUIRED), "p": (F.number, 0)},
    docs={"q": ("number", "the initial position"), "p": ("number", "the initial momentum")},
    state=lambda model, ini, precision: model.initial_state(ini["q"], ini["p"], precision=precision),
))

register_model_kind(ModelKind(
    "harmonic",
    fields={"omega": (F.positive, 1)},
    docs={"omega": ("positive number", "the angular frequency")},
    build=lambda params, base: Harmonic(params["omega"]),
    family="oscillator", label="oscillator",
))
