"""A particle on the sphere |x| = c: the paper's 5-dimensional intermediate coordinates, and the Dirac form.

Intermediate coordinates (paper, section "toy model"), chart with dependent coordinate x3 (x3 != 0)::

    z = (x1, x2, x3, pi1, pi2),   pi_a = p_a - x_a p3 / x3                      (dm3)
    {x1, pi1} = 1, {x2, pi2} = 1, {x3, pi1} = -x1/x3, {x3, pi2} = -x2/x3           (dm5)
    H = (1/2m) [pi1^2 + pi2^2 - (x1 pi1 + x2 pi2)^2 / |x|^2]                       (dm6, corrected: squared)

|x|^2 is a Casimir (the symplectic leaves are the spheres). The chart ends on the equator x3 = 0, where
{x3, pi_a} and pi_a blow up; the same construction with x1 or x2 as the dependent coordinate gives the other two
charts of an atlas (``chart=0, 1, 2``). A run stops cleanly with status ``"chart_edge"`` when
|x_dep| / |x| falls to ``edge``.

:class:`SphereDirac` is the global 6-dimensional form on (x, p) with the Dirac bracket
{x_i, x_j} = 0, {x_i, p_j} = delta_ij - x_i x_j/|x|^2, {p_i, p_j} = (p_i x_j - x_i p_j)/|x|^2, H = |p|^2/2m.
"""

from __future__ import annotations

from fractions import Fraction

import heyoka as hy
from ..precision import thread_mp as mp
import numpy as np

from ..poisson import PoissonSystem
from .. import fields as F
from ..precision import data_bits, export_mpf, resolve_precision, to_fraction
from .base import Model, make_state, state_fractions
from .kinds import InitialFamily, ModelKind, register_initial_family, register_model_kind

__all__ = ["Sphere", "SphereDirac"]


def _positive(value, argname):
    v = to_fraction(value, argname)
    if v <= 0:
        raise ValueError(f"`{argname}` must be positive; got {float(v)}")
    return v


def _vec3(value, argname):
    arr = np.asarray(value, dtype=object)
    if arr.shape != (3,):
        raise ValueError(f"`{argname}` must be three numbers; got shape {arr.shape}")
    return [to_fraction(v, f"{argname}[{i}]") for i, v in enumerate(arr)]


def _fraction_in(value, argname, lo, hi, why: str = "") -> float:
    """A number strictly between ``lo`` and ``hi`` (as a float; a decimal string is read exactly), or an error
    naming ``argname`` (``why``: the reason for the bounds)."""
    if value is None or isinstance(value, bool):
        raise TypeError(f"`{argname}` must be a number in ({lo}, {hi:.4g}); got {type(value).__name__} {value!r}")
    try:
        v = float(to_fraction(value, argname))
    except ValueError:
        if not isinstance(value, str):
            raise
        raise TypeError(f"`{argname}` must be a number in ({lo}, {hi:.4g}) (a decimal string such as '0.1' is read "
                        f"exactly); got str {value!r}") from None
    if not (lo < v < hi):
        raise ValueError(f"`{argname}` must lie in ({lo}, {hi:.4g}){why}; got {v}")
    return v


#: The largest ``edge``: every point has a coordinate with |x_k| >= |x| / sqrt(3), so with an edge below that
#: the chart of the largest coordinate holds every point well inside (an atlas run always has a chart to go to).
EDGE_MAX = 3**-0.5


def _frac_sqrt_float(f: Fraction) -> float:
    return float(f) ** 0.5


class _SphereBase(Model):
    def __init__(self, mass, radius, rtol):
        self.mass_exact = _positive(mass, "mass")
        self.radius_exact = _positive(radius, "radius")
        self._input_bits = {"mass": data_bits([mass]), "radius": data_bits([radius])}
        self.rtol = _fraction_in(rtol, "rtol", 0, 1)

    @property
    def mass(self) -> float:
        return float(self.mass_exact)

    @property
    def radius(self) -> float:
        return float(self.radius_exact)

    def _check_xv(self, x, v):
        """Exact x, v after checking |x| = radius and x.v = 0 to ``rtol``."""
        x = _vec3(x, "x")
        v = _vec3(v, "v")
        r = self.radius_exact
        x2 = sum(c * c for c in x)
        if abs(x2 - r * r) > 2 * self.rtol * r * r:
            raise ValueError(
                f"`x` must lie on the sphere |x| = {float(r)}; got |x| = {_frac_sqrt_float(x2):.17g} "
                f"(relative error {float(abs(x2 - r * r) / (2 * r * r)):.3g} > rtol = {self.rtol:g}). "
                "Scale x to the radius, or change `radius`."
            )
        xv = sum(a * b for a, b in zip(x, v))
        vnorm = _frac_sqrt_float(sum(c * c for c in v))
        if abs(float(xv)) > self.rtol * float(r) * max(vnorm, 1e-300) and xv != 0:
            raise ValueError(
                f"`v` must be tangent to the sphere (x . v = 0); got x . v = {float(xv):.3g} "
                f"(relative {abs(float(xv)) / (float(r) * vnorm):.3g} > rtol = {self.rtol:g}). "
                "Remove the radial part: v - x (x . v) / |x|^2."
            )
        return x, v

    def _chart_model(self, chart):
        """The model that reads a state of chart ``chart`` (self for the Dirac form and for its own chart)."""
        return self

    def _xp_of_rows(self, rows, chart):
        """(x, p) per row; ``chart`` None, one int, or one chart per row."""
        if chart is None or isinstance(chart, (int, np.integer)):
            m = self._chart_model(chart)
            return [m._xp(r) for r in rows]
        charts = list(chart)
        if len(charts) != len(rows):
            raise ValueError(f"`chart` must give one chart per row ({len(rows)}); got {len(charts)}")
        return [self._chart_model(c)._xp(r) for c, r in zip(charts, rows)]

    def position(self, y, chart=None) -> np.ndarray:
        """The position x (three numbers per state), in the state's precision.

        ``chart``: the chart a :class:`Sphere` state is written in (default: the model's own); an int, or one
        chart per row for a 2-d array (e.g. ``sol.charts`` of an atlas run).
        """
        y, chart = self._with_charts(y, chart)
        rows, bits, was_1d = self._rows(y)
        with mp.workprec(bits + 16):
            out = [xp[0] for xp in self._xp_of_rows(rows, chart)]
        return self._out_array(out, bits, was_1d, y if isinstance(y, np.ndarray) else np.asarray(y, dtype=object))

    def velocity(self, y, chart=None) -> np.ndarray:
        """The velocity v = p / m (three numbers per state), in the state's precision; ``chart`` as in
        :meth:`position`."""
        y, chart = self._with_charts(y, chart)
        rows, bits, was_1d = self._rows(y)
        with mp.workprec(bits + 16):
            m = mp.mpf(self.mass_exact.numerator) / self.mass_exact.denominator
            out = [[c / m for c in xp[1]] for xp in self._xp_of_rows(rows, chart)]
        return self._out_array(out, bits, was_1d, y if isinstance(y, np.ndarray) else np.asarray(y, dtype=object))

    def invariants(self, y, chart=None) -> dict:
        """``energy`` |p|^2/2m, ``x2`` = |x|^2 (the Casimir), ``L1, L2, L3`` = x cross p (mpf, in mpmath);
        ``chart`` as in :meth:`position`."""
        y, chart = self._with_charts(y, chart)
        rows, bits, was_1d = self._rows(y)
        keys = ("energy", "x2", "L1", "L2", "L3")
        res = {k: [] for k in keys}
        with mp.workprec(bits + 16):
            m = mp.mpf(self.mass_exact.numerator) / self.mass_exact.denominator
            for x, p in self._xp_of_rows(rows, chart):
                res["energy"].append(mp.fsum(c * c for c in p) / (2 * m))
                res["x2"].append(mp.fsum(c * c for c in x))
                res["L1"].append(x[1] * p[2] - x[2] * p[1])
                res["L2"].append(x[2] * p[0] - x[0] * p[2])
                res["L3"].append(x[0] * p[1] - x[1] * p[0])
        return export_mpf({k: v[0] for k, v in res.items()} if was_1d else res)


    # -- how studies, runs and reports treat it ----------------------------------------------------------------
    closed_form = "great_circle"

    @property
    def compared_names(self) -> tuple:
        return ("x1", "x2", "x3", "v1", "v2", "v3")

    def compared(self, fractions, bits: int, chart=None) -> list:
        """Position and velocity (x, v) through the model's own conversion: the 5-dimensional and the Dirac form
        compare directly, and no chart is needed at the final time."""
        with mp.workprec(bits):
            arr = np.array([mp.mpf(q.numerator) / q.denominator for q in fractions], dtype=object)
        x = self.position(arr, chart=chart) if chart is not None else self.position(arr)
        v = self.velocity(arr, chart=chart) if chart is not None else self.velocity(arr)
        with mp.workprec(bits):
            return [mp.mpf(to_fraction(c).numerator) / to_fraction(c).denominator for c in list(x) + list(v)]

    def plot_quantity(self) -> tuple:
        return "position x", ("x1", "x2", "x3")

    def error_groups(self, n: int) -> list:
        return [(range(0, 3), "norm"), (range(3, 6), "norm")]  # x (scale |x|), v (scale |v|)


class Sphere(_SphereBase):
    """A particle on the sphere in the paper's intermediate coordinates (x1, x2, x3, pi_a, pi_b).

    Parameters
    ----------
    mass, radius : positive numbers (exact input stays exact)
    chart : {0, 1, 2}
        Index of the dependent coordinate (2, the paper's x3, by default); the momenta are those of the other two.
    edge : number in (0, 1/sqrt(3) = 0.577)
        The chart is left when |x_dep| <= edge * radius: states there are refused and runs stop there. Below
        1/sqrt(3), since every point has a coordinate with |x_k| >= |x|/sqrt(3): the chart of the largest
        coordinate then holds every point inside its edge.
    rtol : float
        Tolerance of the checks |x| = radius and x . v = 0 in :meth:`initial_state`.
    atlas : bool
        How the integrators run this model when their ``atlas`` argument is left out: across the atlas of charts
        (True, the default) or in this one chart, stopping at its edge (False).
    """

    def __init__(self, mass=1, radius=1, *, chart: int = 2, edge: float = 0.05, rtol: float = 1e-12,
                 atlas: bool = True):
        super().__init__(mass, radius, rtol)
        if isinstance(chart, bool) or not isinstance(chart, (int, np.integer)):
            raise TypeError(
                f"`chart` must be the int 0, 1 or 2 (the index of the dependent coordinate); got "
                f"{type(chart).__name__} {chart!r}"
            )
        if chart not in (0, 1, 2):
            raise ValueError(f"`chart` must be 0, 1 or 2 (the index of the dependent coordinate); got {chart!r}")
        chart = int(chart)
        # (a fraction of |x|: the largest coordinate is always at least |x|/sqrt(3))
        edge = _fraction_in(edge, "edge", 0, EDGE_MAX, " (1/sqrt(3): every point has a coordinate with "
                            "|x_k| >= |x|/sqrt(3), so below it every point lies inside the chart of its largest "
                            "coordinate)")
        if not isinstance(atlas, bool):
            raise TypeError(f"`atlas` must be True or False; got {atlas!r}")
        self.atlas = atlas
        self.chart = chart
        self.edge = edge
        self.free = tuple(i for i in range(3) if i != chart)
        self.poisson = self._build()

    def _build(self) -> PoissonSystem:
        k = self.chart
        a, b = self.free
        names = ["x1", "x2", "x3", f"pi{a + 1}", f"pi{b + 1}"]
        z = hy.make_vars(*names)
        x = z[:3]
        pia, pib = z[3], z[4]
        P = [[0] * 5 for _ in range(5)]
        # {x_a, pi_a} = 1, {x_b, pi_b} = 1, {x_k, pi_c} = -x_c / x_k
        P[a][3], P[3][a] = 1, -1
        P[b][4], P[4][b] = 1, -1
        P[k][3] = -x[a] / x[k]
        P[3][k] = x[a] / x[k]
        P[k][4] = -x[b] / x[k]
        P[4][k] = x[b] / x[k]
        s = x[a] * pia + x[b] * pib
        H = 0.5 * hy.par[0] * (pia**2 + pib**2 - s**2 / (x[0] ** 2 + x[1] ** 2 + x[2] ** 2))
        return PoissonSystem(
            z,
            P,
            H,
            parameters={"inv_mass": 1 / self.mass_exact, "edge2": Fraction(self.edge) ** 2},
            parameter_sources={"inv_mass": "mass", "edge2": "edge"},
            casimirs={"x2": x[0] ** 2 + x[1] ** 2 + x[2] ** 2},
            name=f"sphere (intermediate, chart x{k + 1})",
            input_bits=self._input_bits,
            jacobi=False,  # the bracket is checked by the tests (tests/test_poisson.py)
        )

    def initial_state(self, x, v, precision=None) -> np.ndarray:
        """State (x1, x2, x3, pi_a, pi_b) from a position on the sphere and a tangent velocity.

        pi_c = m (v_c - x_c v_k / x_k) for the two free indices c (paper eq. dm3). Refuses x off the sphere,
        x . v != 0, and positions on or near the chart edge (|x_k| <= edge * radius).
        """
        given = {"x": x, "v": v}
        x, v = self._check_xv(x, v)
        k = self.chart
        if abs(float(x[k])) <= self.edge * self.radius:
            raise ValueError(
                f"`x` is at the edge of the chart x{k + 1} != 0: |x{k + 1}| = {abs(float(x[k])):.3g} <= "
                f"edge * radius = {self.edge * self.radius:.3g}. Use `chart` = {int(np.argmax(np.abs([float(c) for c in x])))} "
                "(the coordinate of largest magnitude), or the global form SphereDirac."
            )
        m = self.mass_exact
        pis = [m * (v[c] - x[c] * v[k] / x[k]) for c in self.free]
        return make_state(list(x) + pis, precision, inputs=given)

    def check_state(self, y, argname="y0"):
        z = super().check_state(y, argname)
        k = self.chart
        r2 = sum(c * c for c in z[:3])
        if r2 == 0 or abs(float(z[k])) <= self.edge * float(r2) ** 0.5 * (1 - 1e-12):
            raise ValueError(
                f"`{argname}` is at the edge of the chart x{k + 1} != 0 (|x{k + 1}| <= {self.edge} |x|): the bracket "
                f"{{x{k + 1}, pi}} = -x/x{k + 1} blows up there. Start in the chart of the largest coordinate."
            )
        return z

    def events(self):
        k = self.chart
        xk = self.poisson.variables[k]
        x = self.poisson.variables[:3]
        # |x_k| = edge |x|, measured against the state's own |x| (a Casimir, so the radius of the leaf)
        expr = xk**2 - hy.par[1] * (x[0] ** 2 + x[1] ** 2 + x[2] ** 2)
        return [
            (
                expr,
                "chart_edge",
                f"the sphere chart x{k + 1} != 0 is ending (|x{k + 1}| reached {self.edge} * radius)",
            )
        ]

    # -- atlas ---------------------------------------------------------------------------------------------------
    #: |x_dep| / |x| at which an atlas run leaves a chart; the coordinate of largest magnitude always has
    #: |x_k| / |x| >= 1/sqrt(3) = 0.577, so the next chart starts well inside.
    ATLAS_SWITCH = 0.5

    def _chart_model(self, chart):
        if chart is None or chart == self.chart:
            return self
        return self.for_chart(int(chart))

    def for_chart(self, chart: int, edge: float | None = None) -> "Sphere":
        """The same sphere in the chart whose dependent coordinate is ``chart`` (cached)."""
        edge = self.edge if edge is None else edge
        cache = self.__dict__.setdefault("_charts", {})
        key = (int(chart), float(edge))
        if key not in cache:
            if key == (self.chart, self.edge):
                cache[key] = self
            else:
                cache[key] = Sphere(self.mass_exact, self.radius_exact, chart=int(chart), edge=edge, rtol=self.rtol,
                                    atlas=self.atlas)
        return cache[key]

    def best_chart(self, y) -> int:
        """Index of the coordinate of largest magnitude of the state's position: the best chart for it."""
        z = [to_fraction(v, "y") for v in np.asarray(y, dtype=object)[:3]]
        return int(np.argmax([abs(float(c)) for c in z]))

    def change_chart(self, y, chart: int, bits: int = 53) -> list:
        """The same point (x, p) written in chart ``chart``: pi_c = p_c - x_c p_k / x_k (paper eq. dm3).

        Computed with ``bits`` + 32 bits from the state's exact value and returned as mpf at that precision, so
        that the caller rounds once to its working precision.
        """
        if chart not in (0, 1, 2) or isinstance(chart, bool):
            raise ValueError(f"`chart` must be 0, 1 or 2; got {chart!r}")
        exact = getattr(y, "exact", None)
        r = list(exact) if exact is not None else [to_fraction(v, f"y[{i}]") for i, v in
                                                    enumerate(np.asarray(y, dtype=object))]
        if len(r) != 5:
            raise ValueError(f"`y` must be a 5-number sphere state; got {len(r)} numbers")
        with mp.workprec(int(bits) + 32):
            x, p = self._xp(r)
            if x[chart] == 0:
                raise ValueError(f"`chart` x{chart + 1} != 0 cannot hold a point with x{chart + 1} = 0")
            pis = [p[c] - x[c] * p[chart] / x[chart] for c in range(3) if c != chart]
            return export_mpf([+v for v in list(x) + pis])

    def chart_change_expressions(self, chart: int) -> list:
        """The state written in chart ``chart`` as heyoka expressions of this chart's variables (the map of
        :meth:`change_chart`, for engines that evaluate it in their own arithmetic, e.g. on balls)."""
        if chart not in (0, 1, 2) or isinstance(chart, bool):
            raise ValueError(f"`chart` must be 0, 1 or 2; got {chart!r}")
        v = self.poisson.variables
        x = v[:3]
        a, b = self.free
        s = x[a] * v[3] + x[b] * v[4]
        x2 = x[0] ** 2 + x[1] ** 2 + x[2] ** 2
        p = [None] * 3
        p[a] = v[3] - x[a] * s / x2
        p[b] = v[4] - x[b] * s / x2
        p[self.chart] = -x[self.chart] * s / x2
        return list(x) + [p[c] - x[c] * p[chart] / x[chart] for c in range(3) if c != chart]

    def _xp(self, r):
        """(x, p) as mpf lists from an exact 5-number state (paper eq. dm4 with pi_3 = 0)."""
        z = [mp.mpf(v.numerator) / v.denominator for v in r]
        x = z[:3]
        a, b = self.free
        s = x[a] * z[3] + x[b] * z[4]
        x2 = mp.fsum(c * c for c in x)
        p = [None] * 3
        p[a] = z[3] - x[a] * s / x2
        p[b] = z[4] - x[b] * s / x2
        p[self.chart] = -x[self.chart] * s / x2
        return x, p

    @property
    def runs_on_atlas(self) -> bool:
        return bool(self.atlas)

    def atlas_twin(self) -> "SphereDirac":
        """The Dirac form of the same sphere: rows of an atlas run (in several charts) are compared and measured as
        (x, p) states of it."""
        return SphereDirac(mass=self.mass_exact, radius=self.radius_exact, rtol=self.rtol)

    def atlas_state(self, row, chart: int, bits: int):
        """A state written in ``chart``, as the (x, p) state of :meth:`atlas_twin` (``bits`` bits)."""
        prec = resolve_precision(bits)
        arr = prec.array(state_fractions(row, self.dimension, "y"))
        x = self.position(arr, chart=int(chart))
        v = self.velocity(arr, chart=int(chart))
        m = self.mass_exact
        return prec.array([to_fraction(c) for c in x] + [m * to_fraction(c) for c in v])

    def __repr__(self):
        return f"Sphere(mass={self.mass}, radius={self.radius}, chart={self.chart})"


class SphereDirac(_SphereBase):
    """A particle on the sphere in the global 6-dimensional Dirac form (x1, x2, x3, p1, p2, p3).

    Both |x|^2 and x . p are Casimirs of the Dirac bracket; :meth:`initial_state` removes any radial part of
    the velocity exactly so that x . p = 0 holds from the start.
    """

    def __init__(self, mass=1, radius=1, *, rtol: float = 1e-12):
        super().__init__(mass, radius, rtol)
        self.poisson = self._build()

    def _build(self) -> PoissonSystem:
        z = hy.make_vars("x1", "x2", "x3", "p1", "p2", "p3")
        x, p = z[:3], z[3:]
        r2 = x[0] ** 2 + x[1] ** 2 + x[2] ** 2
        P = [[0] * 6 for _ in range(6)]
        for i in range(3):
            for j in range(3):
                e = (1.0 if i == j else 0.0) - x[i] * x[j] / r2
                P[i][3 + j] = e
                P[3 + j][i] = -e
                if i != j:
                    P[3 + i][3 + j] = (p[i] * x[j] - x[i] * p[j]) / r2
        H = 0.5 * hy.par[0] * (p[0] ** 2 + p[1] ** 2 + p[2] ** 2)
        return PoissonSystem(
            z,
            P,
            H,
            parameters={"inv_mass": 1 / self.mass_exact},
            parameter_sources={"inv_mass": "mass"},
            casimirs={"x2": r2, "xp": x[0] * p[0] + x[1] * p[1] + x[2] * p[2]},
            name="sphere (Dirac bracket)",
            input_bits=self._input_bits,
            jacobi=False,  # the bracket is checked by the tests (tests/test_poisson.py)
        )

    def initial_state(self, x, v, precision=None) -> np.ndarray:
        """State (x, p) with p = m v, after checking |x| = radius and x . v = 0 (radial part removed exactly)."""
        given = {"x": x, "v": v}
        x, v = self._check_xv(x, v)
        x2 = sum(c * c for c in x)
        xv = sum(a * b for a, b in zip(x, v))
        v = [v[i] - x[i] * xv / x2 for i in range(3)]
        return make_state(list(x) + [self.mass_exact * c for c in v], precision, inputs=given)

    def _xp(self, r):
        z = [mp.mpf(v.numerator) / v.denominator for v in r]
        return z[:3], z[3:]

    def __repr__(self):
        return f"SphereDirac(mass={self.mass}, radius={self.radius})"


# -- scenes: [model] kind = "sphere" | "sphere_dirac", [initial] x, v ----------------------------------------------
def _edge_field(value, path):
    """A chart's edge: in (0, 1/sqrt(3)) (every point has a coordinate with |x_k| >= |x|/sqrt(3), so below that
    every point lies inside the chart of its largest coordinate)."""
    F.number(value, path, below_one=True, what="a number in (0, 0.577) (below 1/sqrt(3))")
    if to_fraction(value, path) ** 2 >= Fraction(1, 3):
        F.fail(path, "a number in (0, 0.577): below 1/sqrt(3), since every point has a coordinate with "
                     "|x_k| >= |x|/sqrt(3) and so lies inside the chart of its largest coordinate", value)
    return value


_MASS_DOCS = {"mass": ("positive number", "the particle's mass"),
              "radius": ("positive number", "the sphere's radius")}

register_initial_family(InitialFamily(
    "sphere",
    fields={"x": (F.vector3, F.REQUIRED), "v": (F.vector3, F.REQUIRED)},
    docs={"x": ("3 numbers", "the position, on the sphere"), "v": ("3 numbers", "the velocity, tangent to it")},
    state=lambda model, ini, precision: model.initial_state(ini["x"], ini["v"], precision=precision),
))

register_model_kind(ModelKind(
    "sphere",
    fields={"mass": (F.positive, 1), "radius": (F.positive, 1), "chart": (F.integer(0, 2), 2),
            "edge": (_edge_field, 0.05), "atlas": (F.boolean, True)},
    docs={**_MASS_DOCS,
          "chart": ("0 | 1 | 2", "the dependent coordinate of the chart the state is written in"),
          "edge": ("number in (0, 0.577)", "a chart ends where abs(x_chart) <= edge * abs(x); below 1/sqrt(3), "
                   "since every point has a coordinate with abs(x_k) >= abs(x)/sqrt(3)"),
          "atlas": ("boolean", "runs and studies switch charts (true) or stay in one and stop at its edge")},
    build=lambda p, base: Sphere(mass=p["mass"], radius=p["radius"], chart=p["chart"],
                                 edge=float(to_fraction(p["edge"])), atlas=p["atlas"]),
    family="sphere", label="sphere (5-d chart)", data_fields=("mass", "radius"),
))

register_model_kind(ModelKind(
    "sphere_dirac",
    fields={"mass": (F.positive, 1), "radius": (F.positive, 1)},
    docs=dict(_MASS_DOCS),
    build=lambda p, base: SphereDirac(mass=p["mass"], radius=p["radius"]),
    family="sphere", label="sphere (Dirac)", data_fields=("mass", "radius"),
))
