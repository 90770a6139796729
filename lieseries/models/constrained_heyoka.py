"""The derivations of a :class:`~lieseries.models.constrained.ConstrainedSystem` as heyoka expressions: sympy to
heyoka (:class:`HeyokaConverter`, the numbers of the Lagrangian as runtime parameters), the Poisson tensors of the
intermediate and the Dirac forms assembled in heyoka where a symbolic inverse is out of reach, the parameters of a
derived model, and the size beyond which a field is compiled in compact mode.
"""

from __future__ import annotations

from fractions import Fraction

import heyoka as hy
import sympy as sp

from ..expr.rewrite import expand_integer_powers

__all__ = ["assemble_intermediate", "assemble_dirac", "HeyokaConverter", "large_field", "model_parameters",
           "heyoka_tensor", "LARGE_FIELD_NODES"]


def assemble_intermediate(d, conv, z, n):
    """Heyoka tensor, H'_0 and velocity of the intermediate formalism from the pieces of a derivation (p12.1, p24,
    p14.1), for frames whose symbolic expansion is too large: K^-1 as adj(K)/det(K) of the 3x3 or smaller
    generic matrix, every piece shared."""
    F = d["frame"]
    nf = F.shape[0]
    Fh = [[conv(F[i, A]) if F[i, A] != 0 else 0 for A in range(n)] for i in range(nf)]
    M, A, U = d["M"], d["A"], d["U"]
    Mh = [[conv(M[a, b]) if M[a, b] != 0 else 0 for b in range(n)] for a in range(n)]
    Ah = [conv(A[a]) if A[a] != 0 else 0 for a in range(n)]
    Uh = conv(U)
    pis = z[n:]

    def dot(xs, ys):
        terms = [x * y for x, y in zip(xs, ys) if not (zero(x) or zero(y))]
        return hy.sum(terms) if terms else hy.expression(0.0)

    MF = [[dot(Mh[a], Fh[l]) for l in range(nf)] for a in range(n)]  # (M F^T)_{a l}
    K = [[dot([Fh[k][a] for a in range(n)], [MF[a][l] for a in range(n)]) for l in range(nf)] for k in range(nf)]
    gen = sp.Matrix(nf, nf, lambda i, j: sp.Symbol(f"__k{i}_{j}"))
    det_s = gen.det(method="berkowitz")
    adj_s = gen.adjugate(method="berkowitz")
    ks = {gen[i, j]: hy.expression(f"__k{i}_{j}") for i in range(nf) for j in range(nf)}
    subs = {f"__k{i}_{j}": K[i][j] for i in range(nf) for j in range(nf)}
    det = hy.subs(hy.from_sympy(det_s, s_dict=ks), subs)
    Kinv = [[hy.subs(hy.from_sympy(adj_s[i, j], s_dict=ks), subs) / det for j in range(nf)] for i in range(nf)]
    w = [pis[i] - dot(Fh[i], Ah) for i in range(nf)]
    a = [dot(Kinv[i], w) for i in range(nf)]
    H = 0.5 * dot(w, a) + Uh
    v = [dot([Fh[i][A_] for i in range(nf)], a) for A_ in range(n)]
    p = [Ah[A_] + dot(Mh[A_], v) if not zero(Ah[A_]) else dot(Mh[A_], v) for A_ in range(n)]
    m = n + nf
    tensor = [[0] * m for _ in range(m)]
    for i in range(nf):
        for A_ in range(n):
            if not zero(Fh[i][A_]):
                tensor[A_][n + i] = Fh[i][A_]
                tensor[n + i][A_] = -Fh[i][A_]
    qv = z[:n]
    for i in range(nf):
        for j in range(i + 1, nf):
            # c_ij^D = G_iE d_E G_jD - G_jE d_E G_iD (p13), differentiated in heyoka (shared subexpressions)
            terms = []
            for D_ in range(n):
                parts = [Fh[i][E] * hy.diff(Fh[j][D_], qv[E]) for E in range(n)
                         if not zero(Fh[i][E]) and not zero(Fh[j][D_])]
                parts += [-(Fh[j][E] * hy.diff(Fh[i][D_], qv[E])) for E in range(n)
                          if not zero(Fh[j][E]) and not zero(Fh[i][D_])]
                if parts:
                    terms.append(hy.sum(parts) * p[D_])
            if not terms:
                continue
            e = -hy.sum(terms)
            tensor[n + i][n + j] = e
            tensor[n + j][n + i] = -e
    return tensor, H, v


def assemble_dirac(d, conv, n, k):
    """The Dirac tensor T_ij = {z_i, z_j} + {z_i, chi_I} Delta^-1_IJ {z_j, chi_J} (p8.7) assembled in heyoka from
    b = {G, Phi} (symmetric, positive definite: G_q M^-1 G_q^T), c = {Phi, Phi} and {z, chi}, for systems with many
    constraints whose symbolic inverse is out of reach. b^-1 = L^-T D^-1 L^-1 from b = L D L^T (no pivot is needed
    where the constraints are independent), Delta^-1 = [[b^-1 c b^-1, -b^-1], [b^-1, 0]]; every piece shared, a
    few thousand operations (compact mode)."""

    def h(e):
        return 0 if e == 0 else conv(e)

    def dot(xs, ys):
        terms = [x * y for x, y in zip(xs, ys) if not (zero(x) or zero(y))]
        return hy.sum(terms) if terms else 0

    b = [[h(d["b"][i, j]) for j in range(k)] for i in range(k)]
    c = [[h(d["c"][i, j]) for j in range(k)] for i in range(k)]
    zf = [[h(e) for e in row] for row in d["bz"]]
    L = [[0] * k for _ in range(k)]
    D = [0] * k
    for j in range(k):
        D[j] = b[j][j] - dot([L[j][m] for m in range(j)], [L[j][m] * D[m] for m in range(j)]) \
            if j else b[j][j]
        for i in range(j + 1, k):
            num = b[i][j] - dot([L[i][m] for m in range(j)], [L[j][m] * D[m] for m in range(j)]) if j else b[i][j]
            L[i][j] = 0 if zero(num) else num / D[j]
    Linv = [[1 if i == j else 0 for j in range(k)] for i in range(k)]
    for i in range(k):
        for j in range(i):
            acc = dot([L[i][m] for m in range(j, i)], [Linv[m][j] for m in range(j, i)])
            Linv[i][j] = 0 if zero(acc) else -acc
    invD = [1 / D[m] for m in range(k)]
    binv = [[dot([Linv[m][i] * invD[m] for m in range(max(i, j), k) if not zero(Linv[m][i])],
                 [Linv[m][j] for m in range(max(i, j), k) if not zero(Linv[m][i])]) for j in range(k)]
            for i in range(k)]
    cb = [[dot(c[i], [binv[m][j] for m in range(k)]) for j in range(k)] for i in range(k)]
    top = [[dot(binv[i], [cb[m][j] for m in range(k)]) for j in range(k)] for i in range(k)]
    dinv = [top[i] + [0 if zero(x) else -x for x in binv[i]] for i in range(k)] + [binv[i] + [0] * k
                                                                                  for i in range(k)]
    Y = [[dot(dinv[I], zf[j]) for j in range(2 * n)] for I in range(2 * k)]  # (Delta^-1 {z_j, chi}^T)_I
    tensor = [[0] * (2 * n) for _ in range(2 * n)]
    for i in range(2 * n):
        for j in range(i + 1, 2 * n):
            corr = dot(zf[i], [Y[I][j] for I in range(2 * k)])
            canon = 1 if (i < n and j == i + n) else 0
            e = corr + canon if not zero(corr) else canon
            if not zero(e):
                tensor[i][j] = e
                tensor[j][i] = -e
    return tensor


def zero(x) -> bool:
    return isinstance(x, (int, float)) and x == 0


class HeyokaConverter:
    """sympy -> heyoka, with the parameters as runtime parameters and every number that is not a short binary
    number (1/3, 981/100) turned into a runtime parameter of its own (heyoka stores constants as doubles)."""

    def __init__(self, cs, variables):
        self.values = dict(cs.parameter_values)
        self.names = list(self.values)
        self.s_dict = {s: v for s, v in variables}
        for i, k in enumerate(self.names):
            self.s_dict[cs.parameter_symbols[k]] = hy.par[i]
        self.constants = {}

    def __call__(self, expr):
        expr = numbers_as_parameters(sp.sympify(expr), self._parameter)
        return hy.from_sympy(expand_integer_powers(expr), s_dict=self.s_dict)

    def _parameter(self, r):
        """The runtime parameter standing for the rational number ``r`` (one per value)."""
        if r not in self.constants:
            name = f"c{len(self.constants) + 1}"
            while name in self.values:
                name = "_" + name
            self.constants[r] = (len(self.names), name)
            self.names.append(name)
            self.values[name] = Fraction(int(r.p), int(r.q))
            self.s_dict[sp.Symbol(f"__const_{name}")] = hy.par[len(self.names) - 1]
        return sp.Symbol(f"__const_{self.constants[r][1]}")


def numbers_as_parameters(expr, parameter):
    """``expr`` with the numbers heyoka would round to a double made runtime parameters (``parameter(r)`` gives the
    symbol of the rational ``r``): a rational that is not a short binary number (1/3), and every rational inside a
    number that is not rational (sqrt(2), cosh(asinh(1)), 2**(1/3)), which heyoka would fold into one double when
    the expression is built; with its leaves as parameters it is evaluated at each run's precision instead. Short
    binary exponents (the 1/2 of a square root) stay numbers; E becomes exp(1) with 1 a parameter. One pass over
    the shared tree."""
    numeric = {}
    done = {}

    def is_numeric(e):
        r = numeric.get(e)
        if r is None:
            r = numeric[e] = (e.is_Number or isinstance(e, sp.NumberSymbol)) if e.is_Atom else all(
                is_numeric(a) for a in e.args)
        return r

    def walk(e, inside):
        key = (e, inside)
        r = done.get(key)
        if r is not None:
            return r
        if e.is_Rational:
            r = parameter(e) if inside or not dyadic(e) else e
        elif e is sp.E:
            r = sp.exp(parameter(sp.Integer(1)))
        elif e.is_Atom:
            r = e
        else:
            inside = inside or is_numeric(e)
            if isinstance(e, sp.Pow):
                keep = e.exp.is_Rational and dyadic(e.exp)
                r = sp.Pow(walk(e.base, inside), e.exp if keep else walk(e.exp, inside), evaluate=False)
            else:
                args = [walk(a, inside) for a in e.args]
                r = e.func(*args, evaluate=False) if isinstance(e, (sp.Add, sp.Mul)) else e.func(*args)
        done[key] = r
        return r

    return walk(expr, False)


def dyadic(r) -> bool:
    num, den = abs(int(r.p)), int(r.q)
    return den & (den - 1) == 0 and num < 2**53 and den <= 2**60


#: Size (nodes of the sympy trees of the tensor and the Hamiltonian) above which a derived model is compiled by the
#: Taylor integrator in compact mode: unrolled, LLVM took 280 CPU s on the double spherical pendulum's Dirac
#: tensor (12 variables, 12000 operations), compact 5 s; the sphere's (200 nodes) stays unrolled.
LARGE_FIELD_NODES = 3000


def large_field(exprs) -> bool:
    total = 0
    for e in exprs:
        for x in (e if isinstance(e, sp.MatrixBase) else [e]):
            total += sum(1 for _ in sp.preorder_traversal(x))
            if total > LARGE_FIELD_NODES:
                return True
    return False


def model_parameters(system, conv, field_exprs, extra=()):
    """(parameters, sources, bits) of a derived model: the converter's parameters, ``extra`` (name, value, source)
    appended, and an exact unit factor when the last parameter is used by nothing in ``field_exprs`` (heyoka
    counts the parameters of an ODE as 1 + the largest index it uses)."""
    params = {nm: conv.values[nm] for nm in conv.names}
    sources = {nm: f"parameters[{nm!r}]" for nm in system.parameter_values}
    sources.update({nm: "lagrangian" for nm in params if nm not in system.parameter_values})
    for name, value, source in extra:
        while name in params:
            name = "_" + name
        params[name] = value
        sources[name] = source
    used = {int(str(pp)[1:]) for pp in hy.get_params([e for e in field_exprs if isinstance(e, hy.expression)])}
    unit_index = None
    if params and (len(params) - 1) not in used:
        unit = "one"
        while unit in params:
            unit = "_" + unit
        params[unit] = Fraction(1)
        sources[unit] = "lagrangian"
        unit_index = len(params) - 1
    bits = dict(system.parameter_bits)
    bits.update(system.input_bits)
    return params, sources, bits, unit_index


def heyoka_tensor(conv, T):
    m = T.shape[0]
    tensor = [[0] * m for _ in range(m)]
    for a in range(m):
        for b in range(a + 1, m):
            if T[a, b] != 0:
                e = conv(T[a, b])
                tensor[a][b] = e
                tensor[b][a] = -e
    return tensor
