"""Pendulums in Cartesian coordinates, with the Dirac bracket of their constraints.

:class:`SphericalPendulum`
    A mass on a rod of fixed length from a fixed point, in gravity: the particle on the sphere with a potential.
    Coordinates (x, y, z) with z upward; L = m/2 |xdot|^2 - m g z, G = |x|^2 - l^2. Conserved: the energy, the
    vertical angular momentum L3 = x p_y - y p_x, and the Casimirs G, Phi = 2 x . xdot.
:class:`PlanarPendulum`
    The same in a vertical plane: coordinates (x, y), y upward; L = m/2 |xdot|^2 - m g y, G = |x|^2 - l^2.
:class:`DoubleSphericalPendulum`
    Two masses, the first on a rod from the fixed point, the second on a rod from the first: six coordinates
    (x1, y1, z1, x2, y2, z2), z upward, two constraints |r1|^2 - l1^2 and |r2 - r1|^2 - l2^2. Conserved: the energy,
    the vertical angular momentum and the four Casimirs. Its motion is chaotic for most energies: two runs that
    differ in the last bit part exponentially, so a comparison between precisions holds for short times only.

The first two are derived by :class:`~lieseries.models.constrained.ConstrainedSystem` (its ``dirac()`` form, the
state (q, p)); their ``system`` attribute gives the other formulations (``system.reduced()``). The double spherical
pendulum's Dirac bracket is written here from the same formula (paper, p8.7) and assembled in heyoka without
symbolic simplification, its pieces shared: ``ConstrainedSystem``'s derivation of it takes 4 CPU s and its
cancelled rational entries (12000 operations) take the Taylor integrator 5 s to compile in compact mode (280 s
unrolled), against 2 s for this one; its tests check it against ``ConstrainedSystem``'s derivation.

Parameters are kept exact (str such as "9.81", int, Fraction) and become runtime parameters rounded once to each
working precision; a binary float is its own binary value and the model reports it (``poisson.coarse_data()``).
Derivations are cached per parameter values: a second pendulum with the same parameters costs nothing.
"""

from __future__ import annotations

import threading

import heyoka as hy
import numpy as np
import sympy as sp

from .. import fields as F
from ..poisson import PoissonSystem
from ..precision import binary_inputs, data_bits, export_mpf, state_bits, to_fraction
from ..precision import thread_mp as mp
from .base import Model, make_state
from .constrained import ConstrainedSystem
from .constrained_checks import check_surface_residuals
from .kinds import InitialFamily, ModelKind, register_initial_family, register_model_kind

__all__ = ["ConstrainedModel", "SphericalPendulum", "PlanarPendulum", "DoubleSphericalPendulum", "positive",
           "cached_system", "check_positive_parameters"]

_CACHE: dict = {}
_CACHE_LOCK = threading.Lock()


def positive(value, argname):
    """``value`` as an exact Fraction, refused (naming ``argname``) unless it is a finite positive number."""
    v = to_fraction(value, argname)
    if v <= 0:
        raise ValueError(f"`{argname}` must be positive; got {float(v):.17g}")
    return v


def _key(values: dict):
    """A cache key for parameter values: their exact values and the bits binary ones carry (1.0 != "1")."""
    return tuple((k, to_fraction(v), None if data_bits([v]) is None else int(data_bits([v])))
                 for k, v in values.items())


def cached_system(kind: str, values: dict, build):
    """The object ``build()`` makes for the model ``kind`` with these parameter values, built once per values."""
    key = (kind, _key(values))
    with _CACHE_LOCK:
        found = _CACHE.get(key)
    if found is None:
        found = build()
        with _CACHE_LOCK:
            found = _CACHE.setdefault(key, found)
    return found


def check_positive_parameters(model, values, argname, names):
    """Refuse runtime parameter ``values`` (in the order of ``model.poisson.parameter_names``) whose entries named
    ``names`` (lengths, masses, semi-axes) are not positive, naming ``argname``."""
    for nm, v in zip(model.poisson.parameter_names, values):
        if nm in names and not v > 0:
            raise ValueError(f"`{argname}` gives the parameter {nm!r} = {float(v):.17g}; it must be positive (a "
                             f"length, a mass or a semi-axis); the parameters are {list(model.poisson.parameter_names)}")


class ConstrainedModel(Model):
    """A built-in model on (q^A, p_A) with the Dirac bracket of a :class:`ConstrainedSystem` (its ``dirac()``
    form): the same state, ``initial_state(q=, qdot=)``, ``configuration``, ``velocity`` and ``invariants``, plus
    the conserved quantities the model knows (:meth:`extra_invariants`)."""

    #: Parameters (by name) that must be positive when an ensemble sets them (``params=``).
    positive_parameters: tuple = ()

    def check_parameters(self, values, argname: str = "params") -> None:
        check_positive_parameters(self, values, argname, self.positive_parameters)

    def __init__(self, system: ConstrainedSystem):
        self.system = system
        self.formulation = system.dirac()
        self.poisson = self.formulation.poisson

    @property
    def coordinates(self) -> tuple:
        """The names of the configuration coordinates q^A."""
        return self.system.coordinates

    def initial_state(self, q, qdot, precision=None) -> np.ndarray:
        """The state (q, p) from a point on the constraint surface and a tangent velocity (exact input stays
        exact); a point off the surface or a velocity that is not tangent is refused with its residual."""
        return self.formulation.initial_state(q, qdot, precision=precision)

    def check_state(self, y, argname: str = "y0") -> list:
        return self.formulation.check_state(y, argname)

    def events(self):
        return self.formulation.events()

    def configuration(self, y) -> np.ndarray:
        """q^A for a state, each row of a 2-d array, or a Solution."""
        return self.formulation.configuration(y)

    def velocity(self, y) -> np.ndarray:
        """qdot^A = p_A / m in the state's precision."""
        return self.formulation.velocity(y)

    def invariants(self, y) -> dict:
        """``energy``, the Casimirs ``G1..``, ``Phi1..`` and the model's own conserved quantities (mpf; lists for
        rows)."""
        out = dict(self.formulation.invariants(y))
        rows, bits, was_1d = self._rows(y)
        with mp.workprec(bits + 16):
            extra = [self.extra_invariants([mp.mpf(v.numerator) / v.denominator for v in r]) for r in rows]
        for name in (extra[0] if extra else {}):
            vals = export_mpf([e[name] for e in extra])
            out[name] = vals[0] if was_1d else vals
        return out

    def extra_invariants(self, z) -> dict:
        """Conserved quantities beyond the energy and the constraints at one state ``z`` (mpf, at the caller's
        precision); none by default."""
        return {}


def _vertical_momentum(z, pairs):
    """sum of x p_y - y p_x over ``pairs`` of (index of x, index of y, index of p_x, index of p_y)."""
    return mp.fsum(z[ix] * z[py] - z[iy] * z[px] for ix, iy, px, py in pairs)


class SphericalPendulum(ConstrainedModel):
    """A mass ``mass`` on a rod of length ``length`` from the origin, in gravity ``g`` along -z (module docstring).

    State (x, y, z, p_x, p_y, p_z), p = mass * velocity. ``invariants``: ``energy``, ``G1`` = |x|^2 - l^2,
    ``Phi1`` = 2 x . xdot, ``L3`` = x p_y - y p_x (the vertical angular momentum).

    Examples
    --------
    >>> import lieseries as ls
    >>> pend = ls.SphericalPendulum(length=1, mass=1, g="9.81")
    >>> y0 = pend.initial_state(q=("0.6", 0, "-0.8"), qdot=(0, 1, 0))
    """

    positive_parameters = ("length", "mass")

    def __init__(self, length=1, mass=1, g=1):
        positive(length, "length")
        positive(mass, "mass")
        to_fraction(g, "g")
        values = {"length": length, "mass": mass, "g": g}
        system = cached_system("spherical pendulum", values, lambda: ConstrainedSystem(
            "mass/2*(x_dot**2 + y_dot**2 + z_dot**2) - mass*g*z", ["x", "y", "z"], ["x**2 + y**2 + z**2 - length**2"],
            parameters=values, name="spherical pendulum"))
        super().__init__(system)
        self.length_exact, self.mass_exact, self.g_exact = (system.parameter_values[k] for k in ("length", "mass", "g"))

    def extra_invariants(self, z) -> dict:
        return {"L3": _vertical_momentum(z, [(0, 1, 3, 4)])}

    def __repr__(self) -> str:
        return (f"SphericalPendulum(length={float(self.length_exact)}, mass={float(self.mass_exact)}, "
                f"g={float(self.g_exact)})")


class PlanarPendulum(ConstrainedModel):
    """A mass ``mass`` on a rod of length ``length`` in the vertical (x, y) plane, gravity ``g`` along -y.

    State (x, y, p_x, p_y). ``invariants``: ``energy``, ``G1`` = x^2 + y^2 - l^2, ``Phi1`` = 2 x . xdot.

    Examples
    --------
    >>> import lieseries as ls
    >>> pend = ls.PlanarPendulum(length=1, g="9.81")
    >>> y0 = pend.initial_state(q=("0.6", "-0.8"), qdot=(0, 0))
    """

    positive_parameters = ("length", "mass")

    def __init__(self, length=1, mass=1, g=1):
        positive(length, "length")
        positive(mass, "mass")
        to_fraction(g, "g")
        values = {"length": length, "mass": mass, "g": g}
        system = cached_system("planar pendulum", values, lambda: ConstrainedSystem(
            "mass/2*(x_dot**2 + y_dot**2) - mass*g*y", ["x", "y"], ["x**2 + y**2 - length**2"], parameters=values,
            name="planar pendulum"))
        super().__init__(system)
        self.length_exact, self.mass_exact, self.g_exact = (system.parameter_values[k] for k in ("length", "mass", "g"))

    def __repr__(self) -> str:
        return (f"PlanarPendulum(length={float(self.length_exact)}, mass={float(self.mass_exact)}, "
                f"g={float(self.g_exact)})")


# -- the double spherical pendulum ---------------------------------------------------------------------------------


def _dirac_tensor(q, p, masses, constraints, conv):
    """The Dirac tensor {z_i, z_j}_D on z = (q, p) for L = sum m_A/2 qdot_A^2 - U(q) and holonomic constraints
    (paper, p8.1 and p8.7), as heyoka expressions (entries below the diagonal written as the negatives of those
    above); also Phi_alpha = dG_alpha/dq . p/m (sympy). The brackets of the coordinates with the constraints are
    sympy derivatives; ``conv`` turns them into heyoka, where they are assembled without symbolic simplification."""
    n, k = len(q), len(constraints)

    def bracket(f, g):
        return sp.expand(sum(sp.diff(f, q[a]) * sp.diff(g, p[a]) - sp.diff(f, p[a]) * sp.diff(g, q[a])
                             for a in range(n)))

    phi = [sum(sp.diff(g, q[a]) * p[a] / masses[a] for a in range(n)) for g in constraints]
    chi = list(constraints) + phi
    b = [[conv(bracket(constraints[a], phi[c])) for c in range(k)] for a in range(k)]
    c = [[conv(bracket(phi[a], phi[d])) if a < d else 0 for d in range(k)] for a in range(k)]
    for a in range(k):
        for d in range(a):
            c[a][d] = 0 if _zero(c[d][a]) else -c[d][a]
    if k == 1:
        binv = [[1.0 / b[0][0]]]
    elif k == 2:
        det = b[0][0] * b[1][1] - b[0][1] * b[1][0]
        binv = [[b[1][1] / det, -b[0][1] / det], [-b[1][0] / det, b[0][0] / det]]
    else:  # pragma: no cover - the built-in models have one or two constraints
        raise ValueError("internal: at most two constraints")

    def mat(A, B):
        out = []
        for i in range(k):
            row = []
            for j in range(k):
                t = [A[i][m] * B[m][j] for m in range(k) if not _zero(A[i][m]) and not _zero(B[m][j])]
                row.append(hy.sum(t) if t else 0)
            out.append(row)
        return out

    binvT = [[binv[j][i] for j in range(k)] for i in range(k)]
    top = mat(mat(binvT, c), binv)
    # Delta^-1 = [[b^-T c b^-1, -b^-T], [b^-1, 0]], indices over chi = (G, Phi)
    dinv = [[top[i][j] for j in range(k)] + [-binvT[i][j] for j in range(k)] for i in range(k)]
    dinv += [[binv[i][j] for j in range(k)] + [0] * k for i in range(k)]
    # {q^A, f} = df/dp_A, {p_A, f} = -df/dq^A
    zc = [[sp.expand(sp.diff(ch, p[i]) if i < n else -sp.diff(ch, q[i - n])) for ch in chi] for i in range(2 * n)]
    zh = [[0 if e == 0 else conv(e) for e in row] for row in zc]
    tensor = [[0] * (2 * n) for _ in range(2 * n)]
    for i in range(2 * n):
        for j in range(i + 1, 2 * n):
            # {z_i, z_j}_D = J_ij - {z_i, chi_I} Delta^-1_IJ {chi_J, z_j},  {chi_J, z_j} = -{z_j, chi_J}
            terms = [zh[i][I] * dinv[I][J] * zh[j][J] for I in range(2 * k) for J in range(2 * k)
                     if zc[i][I] != 0 and zc[j][J] != 0 and not _zero(dinv[I][J])]
            if i < n and j == i + n:
                terms.append(hy.expression(1.0))
            if terms:
                tensor[i][j] = hy.sum(terms)
                tensor[j][i] = -tensor[i][j]
    return tensor, phi


def _zero(e) -> bool:
    return isinstance(e, (int, float)) and e == 0


def _to_heyoka(e, table, memo=None):
    """sympy -> heyoka for sums, products and integer powers of ``table``'s symbols with dyadic coefficients.

    Integer powers become products: heyoka's Taylor coefficients of pow(x, n) divide by x and give NaN where
    x = 0 (heyoka 7.13: x**3 integrated from x = 0), which a pendulum reaches whenever a coordinate crosses 0."""
    memo = {} if memo is None else memo
    found = memo.get(e)
    if found is not None:
        return found  # one heyoka node per distinct subexpression: the tensor's entries share theirs
    memo[e] = out = _convert(e, table, memo)
    return out


def _convert(e, table, memo):
    if e.is_Symbol:
        return table[e]
    if e.is_Rational:
        if e.q & (e.q - 1) or abs(e.p) >= 2**53:
            raise ValueError(f"internal: the constant {e} is not exact in binary")
        return hy.expression(float(e))
    args = [_to_heyoka(a, table, memo) for a in e.args]
    if e.is_Add:
        return hy.sum(args)
    if e.is_Mul:
        out = args[0]
        for a in args[1:]:
            out = out * a
        return out
    if e.is_Pow and e.exp.is_Integer:
        n = int(e.exp)
        base = args[0]
        out = base
        for _ in range(abs(n) - 1):
            out = out * base
        return out if n > 0 else 1.0 / out
    raise ValueError(f"internal: cannot convert {e.func.__name__} to heyoka")


class DoubleSphericalPendulum(Model):
    """Two masses on rods in gravity ``g`` along -z: ``m1`` at distance ``l1`` from the origin, ``m2`` at
    distance ``l2`` from ``m1`` (module docstring). Chaotic.

    State (x1, y1, z1, x2, y2, z2, p_x1, ..., p_z2), p = mass * velocity. ``invariants``: ``energy``, ``G1`` =
    |r1|^2 - l1^2, ``G2`` = |r2 - r1|^2 - l2^2, ``Phi1``, ``Phi2`` (their time derivatives), ``L3`` (the total
    vertical angular momentum).

    Examples
    --------
    >>> import lieseries as ls
    >>> pend = ls.DoubleSphericalPendulum(l1=1, l2=1, m1=1, m2=1, g="9.81")
    >>> y0 = pend.initial_state(q=("0.6", 0, "-0.8", "0.6", "0.6", "-1.6"), qdot=(0, 1, 0, 1, 1, 0))
    """

    coordinates = ("x1", "y1", "z1", "x2", "y2", "z2")

    def check_parameters(self, values, argname: str = "params") -> None:
        check_positive_parameters(self, values, argname, ("l1", "l2", "m1", "m2"))

    def __init__(self, l1=1, l2=1, m1=1, m2=1, g=1):
        for name, v in (("l1", l1), ("l2", l2), ("m1", m1), ("m2", m2)):
            positive(v, name)
        to_fraction(g, "g")
        given = {"l1": l1, "l2": l2, "m1": m1, "m2": m2, "g": g}
        self.parameter_values = {k: to_fraction(v, k) for k, v in given.items()}
        self._built = cached_system("double spherical pendulum", given, lambda: self._build(given))
        self.poisson = self._built["poisson"]

    def _build(self, given):
        q = sp.symbols("x1 y1 z1 x2 y2 z2", real=True)
        p = sp.symbols("p_x1 p_y1 p_z1 p_x2 p_y2 p_z2", real=True)
        names = list(given)
        par = {k: sp.Symbol(k, real=True) for k in names}  # g may be of either sign
        m1, m2, l1, l2, g = (par[k] for k in ("m1", "m2", "l1", "l2", "g"))
        masses = [m1] * 3 + [m2] * 3
        r1, r2 = q[:3], q[3:]
        G = [sum(c * c for c in r1) - l1**2, sum((b - a) ** 2 for a, b in zip(r1, r2)) - l2**2]
        H = sum(pa * pa / (2 * ma) for pa, ma in zip(p, masses)) + g * (m1 * r1[2] + m2 * r2[2])
        z = hy.make_vars(*[str(s) for s in q + p])
        s_dict = dict(zip(q + p, z))
        s_dict.update({par[k]: hy.par[i] for i, k in enumerate(names)})
        memo = {}

        def conv(e):
            return _to_heyoka(sp.sympify(e), s_dict, memo) if e != 0 else 0

        ht, phi = _dirac_tensor(q, p, masses, G, conv)
        casimirs = {"G1": conv(G[0]), "G2": conv(G[1]), "Phi1": conv(phi[0]), "Phi2": conv(phi[1])}
        bits = {k: data_bits([v]) for k, v in given.items()}
        poisson = PoissonSystem(z, ht, conv(H), parameters={k: to_fraction(v, k) for k, v in given.items()},
                                casimirs=casimirs, name="double spherical pendulum (Dirac bracket)",
                                input_bits=bits, parameter_sources={k: k for k in names}, jacobi=False)
        syms = list(q) + [par[k] for k in names]
        return {"poisson": poisson, "G": [sp.lambdify(syms, e, modules=[{}]) for e in G],
                "terms": [[sp.lambdify(syms, t, modules=[{}]) for t in sp.Add.make_args(sp.expand(e))] for e in G],
                "grad": [[sp.lambdify(syms, sp.diff(e, qa), modules=[{}]) for qa in q] for e in G]}

    # -- states --------------------------------------------------------------------------------------------------
    def _vector(self, value, argname):
        arr = np.asarray(value, dtype=object)
        if arr.shape != (6,):
            raise ValueError(f"`{argname}` must be 6 numbers (one per coordinate {list(self.coordinates)}); got "
                             f"shape {arr.shape}")
        return [to_fraction(v, f"{argname}[{i}]") for i, v in enumerate(arr)]

    def _check_surface(self, q, qdot, bits, qname, vname, loose=False):
        """Refuse a point off the constraints or a velocity not tangent to them, as every constrained model does
        (:func:`~lieseries.models.constrained_checks.check_surface_residuals`); the terms and gradients are
        evaluated in exact rational arithmetic."""
        args = list(q) + [self.parameter_values[k] for k in ("l1", "l2", "m1", "m2", "g")]
        terms = [[t(*args) for t in ts] for ts in self._built["terms"]]
        grads = [[gr(*args) for gr in row] for row in self._built["grad"]]
        labels = ["G1 = |r1|^2 - l1^2", "G2 = |r2 - r1|^2 - l2^2"]
        check_surface_residuals(terms, grads, qdot, bits, labels, qname, vname, loose,
                                coarse_model=self.poisson.coarse_data())

    def initial_state(self, q, qdot, precision=None) -> np.ndarray:
        """The state (q, p), p = m qdot, from a point with |r1| = l1, |r2 - r1| = l2 and a velocity tangent to
        both constraints (exact input stays exact: an ExactState unless ``precision`` is given). Refused, naming
        ``q`` or ``qdot`` with the residual, otherwise."""
        given = {"q": q, "qdot": qdot}
        qf = self._vector(q, "q")
        vf = self._vector(qdot, "qdot")
        binary = {}
        for nm, val in given.items():
            binary.update(binary_inputs(val, nm))
        bits = min(binary.values()) if binary else None
        self._check_surface(qf, vf, bits, "q", "qdot")
        m1, m2 = self.parameter_values["m1"], self.parameter_values["m2"]
        p = [m1 * v for v in vf[:3]] + [m2 * v for v in vf[3:]]
        return make_state(qf + p, precision, inputs=given)

    def check_state(self, y, argname: str = "y0") -> list:
        z = super().check_state(y, argname)
        if getattr(y, "exact", None) is not None:
            bits = getattr(y, "data_bits", None)
        else:
            bits = state_bits(y) if isinstance(y, np.ndarray) and y.dtype != object else data_bits(list(y))
        m1, m2 = self.parameter_values["m1"], self.parameter_values["m2"]
        v = [c / m1 for c in z[6:9]] + [c / m2 for c in z[9:]]
        self._check_surface(z[:6], v, bits, argname, argname, loose=True)
        return z

    def configuration(self, y) -> np.ndarray:
        """(x1, y1, z1, x2, y2, z2) of a state, each row of a 2-d array, or a Solution."""
        y, _ = self._with_charts(y, None)
        arr = y if isinstance(y, np.ndarray) else np.asarray(y, dtype=object)
        if arr.shape[-1] != 12:
            raise ValueError(f"`y` must have 12 entries per state; got shape {arr.shape}")
        return np.asarray(arr)[..., :6]

    def velocity(self, y) -> np.ndarray:
        """The velocities p / m (6 numbers per state), in the state's precision."""
        y, _ = self._with_charts(y, None)
        rows, bits, was_1d = self._rows(y)
        m1, m2 = self.parameter_values["m1"], self.parameter_values["m2"]
        out = [[c / m1 for c in r[6:9]] + [c / m2 for c in r[9:]] for r in rows]
        return self._out_array(out, bits, was_1d, y if isinstance(y, np.ndarray) else np.asarray(y, dtype=object))

    def invariants(self, y) -> dict:
        """``energy``, ``G1``, ``G2``, ``Phi1``, ``Phi2`` and ``L3`` (total vertical angular momentum), mpf (lists
        for rows)."""
        y, _ = self._with_charts(y, None)
        out = dict(self.poisson.invariants(y))
        rows, bits, was_1d = self._rows(y)
        with mp.workprec(bits + 16):
            vals = [_vertical_momentum([mp.mpf(v.numerator) / v.denominator for v in r], [(0, 1, 6, 7), (3, 4, 9, 10)])
                    for r in rows]
        vals = export_mpf(vals)
        out["L3"] = vals[0] if was_1d else vals
        return out

    def __repr__(self) -> str:
        pv = self.parameter_values
        return "DoubleSphericalPendulum(" + ", ".join(f"{k}={float(pv[k])}" for k in ("l1", "l2", "m1", "m2", "g")) + ")"


# -- scenes: [model] kind = "spherical_pendulum" | "planar_pendulum" | "double_spherical_pendulum",
#    [initial] q, qdot (shared by every model on (q^A, p_A) with constraints) ------------------------------------
register_initial_family(InitialFamily(
    "configuration",
    fields={"q": (F.list_of(F.number, allow_scalar=False), F.REQUIRED),
            "qdot": (F.list_of(F.number, allow_scalar=False), F.REQUIRED)},
    docs={"q": ("list of numbers", "the configuration q^A, one number per coordinate, on the constraint surface"),
          "qdot": ("list of numbers", "the velocity dq^A/dt, tangent to the constraint surface")},
    state=lambda model, ini, precision: model.initial_state(ini["q"], ini["qdot"], precision=precision),
))

_PENDULUM_DOCS = {"length": ("positive number", "the rod's length"), "mass": ("positive number", "the mass"),
                  "g": ("number", "the gravitational acceleration (along -z, or -y in the plane)")}

for _kind, _cls in (("spherical_pendulum", SphericalPendulum), ("planar_pendulum", PlanarPendulum)):
    register_model_kind(ModelKind(
        _kind,
        fields={"length": (F.positive, 1), "mass": (F.positive, 1), "g": (F.number, 1)},
        docs=dict(_PENDULUM_DOCS),
        build=lambda p, base, _cls=_cls: _cls(length=p["length"], mass=p["mass"], g=p["g"]),
        family="configuration", label=_kind.replace("_", " "), data_fields=("length", "mass", "g"),
    ))

register_model_kind(ModelKind(
    "double_spherical_pendulum",
    fields={"l1": (F.positive, 1), "l2": (F.positive, 1), "m1": (F.positive, 1), "m2": (F.positive, 1),
            "g": (F.number, 1)},
    docs={"l1": ("positive number", "the first rod's length (from the fixed point)"),
          "l2": ("positive number", "the second rod's length (from the first mass)"),
          "m1": ("positive number", "the first mass"), "m2": ("positive number", "the second mass"),
          "g": ("number", "the gravitational acceleration (along -z)")},
    build=lambda p, base: DoubleSphericalPendulum(l1=p["l1"], l2=p["l2"], m1=p["m1"], m2=p["m2"], g=p["g"]),
    family="configuration", label="double spherical pendulum", data_fields=("l1", "l2", "m1", "m2", "g"),
))
