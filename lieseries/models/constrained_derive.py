"""The symbolic derivation of :class:`~lieseries.models.constrained.ConstrainedSystem` (sympy): the Dirac bracket and
H_0 (paper, p8.1, p8.6, p8.7) and the intermediate formalism (p9-p14.1), once per system in a process.

:func:`derive_dirac` and :func:`derive_intermediate` read a system's ``q_symbols``, ``mass_matrix`` M(q),
``linear_term`` A(q), ``potential`` U(q) and ``constraints`` (L = 1/2 qdot^T M qdot + A . qdot - U) and return
dicts of sympy expressions in the coordinates, the momenta and the parameter symbols; :func:`memoized` keeps each
result for the process (the inputs are immutable sympy trees, so equal keys mean equal derivations). The small
numeric helpers (exact numbers, ranks at 50 digits) serve the checks of the system's input.
"""

from __future__ import annotations

import threading
from fractions import Fraction

import sympy as sp

from ..precision import thread_mp as mp

__all__ = ["derive_dirac", "derive_intermediate", "memoized", "exact_number", "to_mp", "show_number",
           "numeric_rank", "canonical_bracket", "tidy", "symbolic_inverse", "lie_bracket"]


def exact_number(expr, dps):
    """A sympy number as a Fraction (exact) or an mpf at ``dps`` digits."""
    expr = sp.sympify(expr)
    if isinstance(expr, sp.Rational):
        return Fraction(int(expr.p), int(expr.q))
    val = expr.evalf(dps + 10)
    if not val.is_number or val.has(sp.I):
        raise ValueError(f"not a real number: {expr}")
    with mp.workdps(dps + 10):
        return mp.mpf(sp.Float(val, dps + 10)._mpf_)


def to_mp(v):
    return mp.mpf(v.numerator) / v.denominator if isinstance(v, Fraction) else v


def show_number(v):
    return f"{float(v):.6g}" if isinstance(v, Fraction) else mp.nstr(v, 8)


def numeric_rank(A) -> int:
    """Rank of a matrix of numbers: exact when rational, else numerical at 50 digits."""
    if all(isinstance(e, sp.Rational) for e in A):
        return A.rank()
    with mp.workdps(60):
        B = mp.matrix([[mp.mpf(sp.Float(e.evalf(70), 70)._mpf_) for e in row] for row in A.tolist()])
        s = mp.svd_r(B, compute_uv=False)
        big = max(abs(x) for x in s) if len(s) else 0
        return sum(1 for x in s if abs(x) > big * mp.mpf(10) ** -40)


def canonical_bracket(f, g, q, p):
    return sum(sp.diff(f, q[a]) * sp.diff(g, p[a]) - sp.diff(f, p[a]) * sp.diff(g, q[a]) for a in range(len(q)))


def tidy(e):
    e = sp.cancel(sp.together(e))
    return sp.factor_terms(e)


def _dirac_combination(bs, cs_, bz, n, k):
    """(b, c, T): b = {G, Phi}, c = {Phi, Phi} and the Dirac tensor T_ij = {z_i, z_j} - {z_i, chi_I} Delta^-1_IJ
    {chi_J, z_j} (p8.1, p8.7) from the canonical brackets ``bs`` = {G_a, Phi_c}, ``cs_`` = {Phi_a, Phi_d} (a < d)
    and ``bz`` = {z_i, chi_I}.

    The combination is done in a field of rational functions (sympy's sparse polynomials, one gcd per operation on
    small pieces): expression-level together/cancel on the assembled entries took 25 s for the double spherical
    pendulum, the same result here takes a few. Expressions the field cannot hold (a domain that is not the
    rationals) take the expression route."""
    from sympy.polys.fields import sfield

    flat = [e for row in bs for e in row] + [e for row in cs_ for e in row] + [e for row in bz for e in row]
    try:
        K, els = sfield([sp.sympify(e) for e in flat])
    except Exception:  # sympy refuses some expressions as polynomial generators: the expression route then
        K = None
    if K is None or not (K.domain.is_ZZ or K.domain.is_QQ):
        return _dirac_combination_expr(bs, cs_, bz, n, k)
    it = iter(els)
    bf = [[next(it) for _ in range(k)] for _ in range(k)]
    cf = [[next(it) for _ in range(k)] for _ in range(k)]
    zf = [[next(it) for _ in range(2 * k)] for _ in range(2 * n)]
    for a in range(k):
        for d in range(a):
            cf[a][d] = -cf[d][a]
    binv = _field_inverse(bf, K)
    if binv is None:
        raise ValueError("internal: the Dirac matrix {G, Phi} is singular")
    binvT = [list(r) for r in zip(*binv)]
    top = _field_mul(_field_mul(binvT, cf, K), binv, K)
    # Delta^-1 = [[b^-T c b^-1, -b^-T], [b^-1, 0]] over chi = (G, Phi)
    dinv = [top[i] + [-x for x in binvT[i]] for i in range(k)] + [binv[i] + [K.zero] * k for i in range(k)]
    T = sp.zeros(2 * n, 2 * n)
    for i in range(2 * n):
        for j in range(i + 1, 2 * n):
            acc = K.one if (i < n and j == i + n) else K.zero
            for I in range(2 * k):
                if not zf[i][I]:
                    continue
                for J in range(2 * k):
                    if dinv[I][J] and zf[j][J]:
                        acc += zf[i][I] * dinv[I][J] * zf[j][J]  # - {z_i, chi_I} D_IJ {chi_J, z_j}
            e = _field_expr(acc)
            T[i, j] = e
            T[j, i] = -e
    b = sp.Matrix(k, k, lambda a, d: _field_expr(bf[a][d]))
    c = sp.Matrix(k, k, lambda a, d: _field_expr(cf[a][d]) if a != d else 0)
    return b, c, T


def _field_mul(X, Y, K):
    return [[sum((X[i][m] * Y[m][j] for m in range(len(Y))), K.zero) for j in range(len(Y[0]))]
            for i in range(len(X))]


def solve_linear(D, r):
    """The solution x of D x = r (D a k x k sympy matrix, r k expressions) as reduced sympy expressions, in a field
    of rational functions like the Dirac tensor (by sympy's LU and cancel where the field cannot hold the
    entries); None when D is singular as a matrix of functions."""
    from sympy.polys.fields import sfield

    k = D.shape[0]
    try:
        K, els = sfield([sp.sympify(e) for e in list(D) + list(r)])
    except Exception:  # sympy refuses some expressions as polynomial generators: the expression route then
        K = None
    if K is None or not (K.domain.is_ZZ or K.domain.is_QQ):
        if sp.cancel(D.det(method="berkowitz")) == 0:
            return None
        return [sp.cancel(e) for e in D.LUsolve(sp.Matrix(r))]
    inv = _field_inverse([els[i * k:(i + 1) * k] for i in range(k)], K)
    if inv is None:
        return None
    rf = els[k * k:]
    return [_field_expr(sum((inv[i][j] * rf[j] for j in range(k)), K.zero)) for i in range(k)]


def substitute(exprs, f):
    """``exprs`` (sympy expressions) with the symbols of ``f`` replaced by its expressions, each result reduced:
    in one field of rational functions when the expressions are polynomials in those symbols over a denominator
    free of them (the Dirac tensor and H_0 are, in the momenta), else by ``tidy`` of the substitution. The field
    route groups each numerator's terms by their powers of the replaced symbols: a few field products per entry
    instead of an expression-level cancel of the whole substituted entry."""
    from sympy.polys.fields import sfield

    keys = list(f)
    exprs = [sp.sympify(e) for e in exprs]
    try:
        K, els = sfield(exprs + [sp.sympify(f[x]) for x in keys] + keys)
    except Exception:
        K = None
    if K is None or not (K.domain.is_ZZ or K.domain.is_QQ):
        return [tidy(e.xreplace(f)) if e != 0 else e for e in exprs]
    m = len(exprs)
    vals, gens = els[m:m + len(keys)], els[m + len(keys):]
    idx = []
    for g in gens:  # each replaced symbol must be a generator of the field's ring
        num = g.numer
        if g.denom != 1 or len(num) != 1 or sum(next(iter(num.itermonoms()))) != 1:
            return [tidy(e.xreplace(f)) if e != 0 else e for e in exprs]
        idx.append(next(iter(num.itermonoms())).index(1))
    out = []
    for e, x in zip(exprs, els[:m]):
        if any(x.denom.degree(i) > 0 for i in idx):
            out.append(tidy(e.xreplace(f)))
            continue
        buckets = {}
        for monom, c in x.numer.items():
            key = tuple(monom[i] for i in idx)
            rest = list(monom)
            for i in idx:
                rest[i] = 0
            buckets.setdefault(key, {})[tuple(rest)] = c
        acc = K.zero
        for key, terms in buckets.items():
            term = K(x.numer.ring(terms))
            for v, power in zip(vals, key):
                if power:
                    term *= v ** power
            acc += term
        out.append(_field_expr(acc / K(x.denom)))
    return out


def _field_inverse(B, K):
    """Inverse of a small square matrix of field elements: the generic adjugate over the determinant (None when
    it is singular)."""
    d = len(B)
    gen = sp.Matrix(d, d, lambda i, j: sp.Symbol(f"__k{i}_{j}"))
    det = _field_eval(gen.det(method="berkowitz"), gen, B, K)
    if not det:
        return None
    adj = gen.adjugate(method="berkowitz")
    return [[_field_eval(adj[i, j], gen, B, K) / det for j in range(d)] for i in range(d)]


def _field_eval(poly, gen, B, K):
    """The polynomial ``poly`` in the generic entries ``gen`` at the field elements ``B``."""
    d = len(B)
    P = sp.Poly(poly, *[gen[i, j] for i in range(d) for j in range(d)])
    vals = [B[i][j] for i in range(d) for j in range(d)]
    out = K.zero
    for monom, coeff in P.terms():
        term = K(coeff)
        for v, e in zip(vals, monom):
            if e:
                term *= v ** e
        out += term
    return out


def _field_expr(x):
    """A field element as a sympy expression: numerator and denominator with their integer content and common
    monomial pulled out (what factor_terms does, on the polynomials, at a fraction of its cost)."""
    num, den = x.numer, x.denom
    if not num:
        return sp.Integer(0)
    syms = x.field.ring.symbols
    factor = sp.Integer(1)
    parts = []
    for poly, power in ((num, 1), (den, -1)):
        content, poly = poly.primitive()
        if poly.LC < 0:
            content, poly = -content, -poly
        monom = tuple(min(es) for es in zip(*poly.itermonoms()))
        if any(monom):
            poly = poly.ring({tuple(a - b for a, b in zip(m, monom)): c for m, c in poly.items()})
        factor *= (sp.Integer(content) * sp.Mul(*[s ** e for s, e in zip(syms, monom)])) ** power
        parts.append(poly.as_expr())
    return factor * parts[0] / parts[1]


def _dirac_combination_expr(bs, cs_, bz, n, k):
    """:func:`_dirac_combination` with sympy expressions (together/cancel per entry)."""
    b = sp.Matrix(k, k, lambda a, d: tidy(bs[a][d]))
    c = sp.Matrix(k, k, lambda a, d: (tidy(cs_[a][d]) if a < d else -tidy(cs_[d][a])) if a != d else 0)
    binv = symbolic_inverse(b).applyfunc(sp.cancel)
    Dinv = sp.zeros(2 * k, 2 * k)
    Dinv[:k, :k] = (binv.T * c * binv).applyfunc(sp.cancel)
    Dinv[:k, k:] = -binv.T
    Dinv[k:, :k] = binv
    T = sp.zeros(2 * n, 2 * n)
    for i in range(2 * n):
        for j in range(i + 1, 2 * n):
            canon = 1 if (i < n and j == i + n) else 0
            corr = 0
            for I in range(2 * k):
                if bz[i][I] == 0:
                    continue
                for J in range(2 * k):
                    if Dinv[I, J] == 0 or bz[j][J] == 0:
                        continue
                    corr += bz[i][I] * Dinv[I, J] * (-bz[j][J])  # {chi_J, z_j} = -{z_j, chi_J}
            e = tidy(canon - corr)
            T[i, j] = e
            T[j, i] = -e
    return b, c, T


#: Above this many constraints the Dirac tensor is not derived symbolically but assembled by the models from b = {G, Phi},
#: c = {Phi, Phi} and {z, chi} (``tensor`` is None in :func:`derive_dirac`'s result).
SYMBOLIC_DIRAC_MAX_CONSTRAINTS = 2


def derive_dirac(cs):
    n = len(cs.q_symbols)
    k = len(cs.constraints)
    q = list(cs.q_symbols)
    p = [sp.Symbol(f"p_{c}", real=True) for c in cs.coordinates]
    M, A, U = cs.mass_matrix, cs.linear_term, cs.potential
    Minv = M.inv(method="LU") if any(M[i, j] != 0 for i in range(n) for j in range(n) if i != j) else \
        sp.diag(*[1 / M[i, i] for i in range(n)])
    Minv = Minv.applyfunc(sp.cancel)
    P = sp.Matrix(p)
    v = (Minv * (P - A)).applyfunc(sp.cancel)
    H0 = sp.expand((((P - A).T * Minv * (P - A))[0, 0]) / 2 + U)
    G = list(cs.constraints)
    Phi = [sp.expand(sum(sp.diff(g, q[a]) * v[a] for a in range(n))) for g in G]
    chi = G + Phi
    # each derivative once: dchi/dq and dchi/dp (G has no p); {q_a, chi} = dchi/dp_a, {p_a, chi} = -dchi/dq_a
    dq = [[sp.diff(ch, qa) for qa in q] for ch in chi]
    dp = [[0] * n for _ in G] + [[sp.diff(ph, pa) for pa in p] for ph in Phi]
    bz = [[dp[I][a] for I in range(2 * k)] for a in range(n)] + [[-dq[I][a] for I in range(2 * k)] for a in range(n)]
    bs = [[sp.expand(sum(dq[a][e] * dp[k + c][e] for e in range(n))) for c in range(k)] for a in range(k)]
    cs_ = [[sp.expand(sum(dq[k + a][e] * dp[k + d][e] - dp[k + a][e] * dq[k + d][e] for e in range(n)))
            if a < d else 0 for d in range(k)] for a in range(k)]
    out = {"q": q, "p": p, "H0": H0, "velocity": list(v), "chi": chi, "G": G, "Phi": Phi, "bz": bz}
    if k > SYMBOLIC_DIRAC_MAX_CONSTRAINTS:
        # b^-1 as rational functions is out of reach (R^T R = 1: a 6 x 6 matrix of quadratics in nine variables,
        # its determinant of degree 12; 150 s were not enough): the models assemble the tensor from these pieces
        c = sp.Matrix(k, k, lambda a, d: cs_[a][d] if a < d else (-cs_[d][a] if a > d else 0))
        out.update(tensor=None, b=sp.Matrix(bs), c=c)
        return out
    b, c, T = _dirac_combination(bs, cs_, bz, n, k)
    out.update(tensor=T, b=b, c=c)
    return out


_MEMO: dict = {}
_MEMO_LOCK = threading.Lock()


def memoized(key, derive):
    """The derivation ``derive()`` once per ``key`` in this process (symbolic results are immutable and shared by
    every system with the same inputs); one derivation at a time."""
    with _MEMO_LOCK:
        if key not in _MEMO:
            _MEMO[key] = derive()
        return _MEMO[key]


def _small(e, limit=400) -> bool:
    return sp.count_ops(e) <= limit


def lie_bracket(Fi, Fj, q):
    """[G_i, G_j]^D = G_iE d_E G_jD - G_jE d_E G_iD (paper, p13)."""
    n = len(q)
    return [sum(Fi[E] * sp.diff(Fj[D], q[E]) - Fj[E] * sp.diff(Fi[D], q[E]) for E in range(n)) for D in range(n)]


def symbolic_inverse(K, cancel: bool = True):
    """Inverse of a small symbolic matrix, entries simplified when that is cheap (``cancel=False``: never; the
    adjugate over the determinant as written)."""
    d = K.shape[0]
    if d == 1:
        return sp.Matrix([[1 / K[0, 0]]])
    if all(K[i, j] == 0 for i in range(d) for j in range(d) if i != j):
        return sp.diag(*[1 / K[i, i] for i in range(d)])
    # the generic d x d adjugate and determinant, then the entries put in (no expansion of large entries)
    gen = sp.Matrix(d, d, lambda i, j: sp.Symbol(f"__k{i}_{j}"))
    sub = {gen[i, j]: K[i, j] for i in range(d) for j in range(d)}
    det = gen.det(method="berkowitz").xreplace(sub)
    adj = gen.adjugate(method="berkowitz").xreplace(sub)
    if cancel and _small(det) and all(_small(e) for e in adj):
        det = sp.cancel(det)
        return adj.applyfunc(lambda e: sp.cancel(e / det))
    return adj / det


def derive_intermediate(cs, dependent, F, names):
    """The intermediate formalism (paper, p9-p14.1) for the frame F (rows G_i; None: the chart of p9).

    With W = G_q M^-1 and the momenta pi_i = G_iA p_A, the point p of the intermediate submanifold Phi = W (p - A)
    = 0 with given pi is p = A + M G^T K^-1 (pi - G A), K = G M G^T (the velocity v = M^-1 (p - A) is tangent,
    v = G^T a, and G p = pi fixes a): this is p = G~ pi with pi_alpha = f_alpha(q, pi_i) of p10 and p19.0, written
    without the n x n inverse G~. H'_0 = 1/2 v^T M v + U at that point (p14.1)."""
    n = len(cs.q_symbols)
    k = len(cs.constraints)
    d = n - k
    q = list(cs.q_symbols)
    Gq = sp.Matrix([[sp.diff(g, qa) for qa in q] for g in cs.constraints])
    out = {"q": q, "G": list(cs.constraints), "dependent": dependent}
    if F is None:
        free = [i for i in range(n) if i not in dependent]
        D = Gq[:, list(dependent)]
        detD = sp.cancel(D.det(method="berkowitz"))
        if detD == 0:
            raise ValueError(f"`dependent`: the constraints cannot be solved for "
                             f"{[cs.coordinates[a] for a in dependent]} (the block dG/dq of these coordinates is "
                             "singular everywhere); choose other coordinates")
        Dinv = symbolic_inverse(D)
        F = sp.zeros(d, n)
        for r, i in enumerate(free):
            F[r, i] = 1
            col = -(Dinv * Gq[:, i])
            for a, dep in enumerate(dependent):
                F[r, dep] = tidy(col[a])
        out["detD"] = detD
        out["gram"] = sp.cancel((Gq * Gq.T).det(method="berkowitz"))
    pi = [sp.Symbol(nm, real=True) for nm in names]
    M, A, U = cs.mass_matrix, cs.linear_term, cs.potential
    simplify = dependent is not None  # a chart's frame is simple; a frame of your own may be large (R^-T)
    out.update({"pi": pi, "frame": F, "M": M, "A": A, "U": U})
    if not simplify:
        # the Lie brackets c_ij, K, its inverse, H'_0 and the bracket of the pi are assembled from these pieces
        # in heyoka (ConstrainedIntermediate), where common pieces stay shared: expanding them symbolically costs
        # minutes for the rigid body
        out.update({"c": None, "K": F * M * F.T, "H": None, "velocity": None, "p": None, "tensor": None})
        return out
    raw = {(i, j): lie_bracket(F.row(i), F.row(j), q) for i in range(d) for j in range(i + 1, d)}
    done = _intermediate_in_field(F, M, A, U, pi, raw, n, d)
    if done is not None:
        out.update(done)
        return out
    c = {key: [sp.cancel(e) for e in cij] for key, cij in raw.items()}
    out["c"] = c
    K = (F * M * F.T).applyfunc(sp.cancel)
    Kinv = symbolic_inverse(K)
    w = sp.Matrix(pi) - F * A
    a = Kinv * w
    v = (F.T * a).applyfunc(tidy)
    p = (A + M * v).applyfunc(tidy)
    H = tidy((w.T * a)[0, 0] / 2 + U)
    T = sp.zeros(n + d, n + d)
    for i in range(d):
        for A_ in range(n):
            if F[i, A_] != 0:
                T[A_, n + i] = F[i, A_]
                T[n + i, A_] = -F[i, A_]
    for (i, j), cij in c.items():
        if all(e == 0 for e in cij):
            continue
        e = tidy(-sum(cij[D_] * p[D_] for D_ in range(n) if cij[D_] != 0))
        T[n + i, n + j] = e
        T[n + j, n + i] = -e
    out.update({"K": K, "H": H, "velocity": list(v), "p": list(p), "tensor": T})
    return out




def _intermediate_in_field(F, M, A, U, pi, raw, n, d):
    """c, K, H'_0, qdot, p(q, pi) and the tensor of the intermediate formalism (as in :func:`derive_intermediate`)
    computed in a field of rational functions, each fraction kept reduced: the expression route (together, cancel,
    factor_terms on assembled entries) took 120 CPU s for the double spherical pendulum's chart. None when the
    expressions do not fit such a field (the expression route then)."""
    from sympy.polys.fields import sfield

    flat = ([F[i, a] for i in range(d) for a in range(n)] + [M[a, b] for a in range(n) for b in range(n)]
            + [A[a] for a in range(n)] + [U] + list(pi) + [e for cij in raw.values() for e in cij])
    try:
        K_, els = sfield([sp.sympify(e) for e in flat])
    except Exception:  # sympy refuses some expressions as polynomial generators: the expression route then
        return None
    if not (K_.domain.is_ZZ or K_.domain.is_QQ):
        return None
    it = iter(els)
    Ff = [[next(it) for _ in range(n)] for _ in range(d)]
    Mf = [[next(it) for _ in range(n)] for _ in range(n)]
    Af = [next(it) for _ in range(n)]
    Uf = next(it)
    pif = [next(it) for _ in range(d)]
    cf = {key: [next(it) for _ in range(n)] for key in raw}

    def dot(xs, ys):
        return sum((x * y for x, y in zip(xs, ys) if x and y), K_.zero)

    MFt = [[dot(Mf[a], Ff[l]) for l in range(d)] for a in range(n)]  # (M F^T)_{a l}
    Kf = [[dot([Ff[i][a] for a in range(n)], [MFt[a][l] for a in range(n)]) for l in range(d)] for i in range(d)]
    Kinv = _field_inverse(Kf, K_)
    if Kinv is None:
        raise ValueError("internal: the kinetic matrix of the frame is singular")
    w = [pif[i] - dot(Ff[i], Af) for i in range(d)]
    a = [dot(Kinv[i], w) for i in range(d)]
    v = [dot([Ff[i][b] for i in range(d)], a) for b in range(n)]
    p = [Af[b] + dot(Mf[b], v) for b in range(n)]
    H = dot(w, a) / 2 + Uf
    T = sp.zeros(n + d, n + d)
    for i in range(d):
        for b in range(n):
            if F[i, b] != 0:
                T[b, n + i] = F[i, b]
                T[n + i, b] = -F[i, b]
    for (i, j), cij in cf.items():
        e = _field_expr(-dot(cij, p))
        if e != 0:
            T[n + i, n + j] = e
            T[n + j, n + i] = -e
    return {"c": {key: [_field_expr(x) for x in cij] for key, cij in cf.items()},
            "K": sp.Matrix(d, d, lambda i, j: _field_expr(Kf[i][j])), "H": _field_expr(H),
            "velocity": [_field_expr(x) for x in v], "p": [_field_expr(x) for x in p], "tensor": T}
