"""The Gauss-Newton step's linear algebra against a dense solve of the same KKT system, and
the buffered evaluation of the interval functions against CasADi's own call."""
import casadi as ca
import numpy as np
import pytest

from greybox.fitting.gauss_newton import BorderedKKT
from greybox.shooting import BufferedFunction


def dense_kkt(flights, H, g, S, c, mu, q2):
    """The KKT matrix and right-hand side written out densely from their definition: node
    rows ``Hd dz + sum G^T lam = -g``, interval rows ``S dz_from - dx_to - q^2 lam = -c``,
    the parameters one vector shared by every node. Unknowns: all node states, all
    multipliers, then the parameters."""
    nx = S.shape[1]
    nth = S.shape[2] - nx
    n_nodes, n_int = H.shape[0], S.shape[0]
    nX, nL = n_nodes * nx, n_int * nx
    n = nX + nL + nth
    K = np.zeros((n, n))
    r = np.zeros(n)
    d = np.einsum("kii->ki", H)
    floor = 1e-10 * max(float(d.max()), 1.0)
    X = lambda k: slice(k * nx, (k + 1) * nx)                       # noqa: E731
    L = lambda j: slice(nX + j * nx, nX + (j + 1) * nx)             # noqa: E731
    T = slice(nX + nL, n)
    for k in range(n_nodes):
        Hd = H[k] + np.diag(mu * d[k])
        K[X(k), X(k)] += Hd[:nx, :nx] + floor * np.eye(nx)
        K[X(k), T] += Hd[:nx, nx:]
        K[T, X(k)] += Hd[nx:, :nx]
        K[T, T] += Hd[nx:, nx:]
        r[X(k)] -= g[k, :nx]
        r[T] -= g[k, nx:]
    K[T, T] += floor * np.eye(nth)
    j = node = 0
    for _, M in flights:
        for i in range(M):
            a, b = node + i, node + i + 1
            K[L(j), X(a)] = S[j, :, :nx]
            K[X(a), L(j)] = S[j, :, :nx].T
            K[L(j), T] = S[j, :, nx:]
            K[T, L(j)] = S[j, :, nx:].T
            K[L(j), X(b)] = -np.eye(nx)
            K[X(b), L(j)] = -np.eye(nx)
            if q2 is not None:
                K[L(j), L(j)] = -np.diag(np.broadcast_to(q2, (n_int, nx))[j])
            r[L(j)] = -c[j]
            j += 1
        node += M + 1
    return K, r, nX, nL


def random_problem(rng, flights, nx, nth):
    n_nodes = sum(M + 1 for _, M in flights)
    n_int = sum(M for _, M in flights)
    nz = nx + nth
    J = rng.normal(size=(n_nodes, 2 * nz, nz))
    H = np.einsum("kai,kaj->kij", J, J)
    last = np.cumsum([M + 1 for _, M in flights]) - 1
    H[last] = 0.0                        # a flight's last node has no interval of its own
    g = rng.normal(size=(n_nodes, nz))
    S = rng.normal(size=(n_int, nx, nz)) * 0.5
    S[:, :, :nx] += np.eye(nx)
    c = rng.normal(size=(n_int, nx)) * 0.1
    return H, g, S, c


@pytest.mark.parametrize("flights", [[(0, 12)], [(0, 7), (7, 5)]])
@pytest.mark.parametrize("soft", [None, "per state", "per interval"])
@pytest.mark.parametrize("mu", [0.0, 1e-2, 1e3])
def test_step_equals_the_dense_kkt_solution(flights, soft, mu):
    rng = np.random.default_rng(7)
    nx, nth = 4, 3
    H, g, S, c = random_problem(rng, flights, nx, nth)
    n_int = S.shape[0]
    q2 = None if soft is None else (rng.uniform(0.01, 1.0, nx) if soft == "per state"
                                    else rng.uniform(0.01, 1.0, (n_int, nx)))
    K, r, nX, nL = dense_kkt(flights, H, g, S, c, mu, q2)
    ref = np.linalg.solve(K, r)
    dz, lam = BorderedKKT(flights, nx, nth).solve(H, g, S, c, mu, q2=q2)
    assert np.allclose(dz[:, :nx].ravel(), ref[:nX], rtol=1e-8, atol=1e-10)
    assert np.allclose(dz[:, nx:], ref[nX + nL:][None, :], rtol=1e-8, atol=1e-10)
    assert np.allclose(lam.ravel(), ref[nX:nX + nL], rtol=1e-8, atol=1e-10)


@pytest.mark.parametrize("soft", [False, True])
def test_parameter_inverse_is_the_parameter_block_of_the_inverse(soft):
    rng = np.random.default_rng(3)
    flights, nx, nth = [(0, 9), (9, 6)], 3, 4
    H, g, S, c = random_problem(rng, flights, nx, nth)
    q2 = rng.uniform(0.05, 0.5, nx) if soft else None
    K, _, nX, nL = dense_kkt(flights, H, g, S, c, 0.0, q2)
    P_ref = np.linalg.inv(K)[nX + nL:, nX + nL:]
    P = BorderedKKT(flights, nx, nth).parameter_inverse(H, S, q2=q2)
    assert np.allclose(P, P_ref, rtol=1e-7, atol=1e-12)
    # a covariance: symmetric, positive definite
    assert np.allclose(P, P.T, rtol=1e-9) and np.all(np.linalg.eigvalsh(0.5 * (P + P.T)) > 0)


def test_soft_step_falls_back_to_the_kkt_when_not_positive_definite():
    """An indefinite curvature (no Gauss-Newton matrix is, but a caller's may be) makes the
    Cholesky of the soft normal equations fail; the step then comes from the KKT system and
    still solves it."""
    rng = np.random.default_rng(11)
    flights, nx, nth = [(0, 8)], 3, 2
    H, g, S, c = random_problem(rng, flights, nx, nth)
    H[2, 0, 0] = -1e3
    q2 = np.full(nx, 0.1)
    K, r, nX, nL = dense_kkt(flights, H, g, S, c, 0.0, q2)
    dz, lam = BorderedKKT(flights, nx, nth).solve(H, g, S, c, 0.0, q2=q2)
    assert np.allclose(dz[:, :nx].ravel(), np.linalg.solve(K, r)[:nX], rtol=1e-7, atol=1e-9)


def test_buffered_function_matches_casadis_call():
    x = ca.MX.sym("x", 3)
    p = ca.MX.sym("p", 2)
    U = ca.MX.sym("U", 2, 4)
    f = ca.Function("f", [x, p, U], [ca.vertcat(x * p[0], p[1]), ca.mtimes(U.T, U), ca.sum1(x)])
    m = f.map(5, "serial")
    rng = np.random.default_rng(0)
    X = rng.normal(size=(3, 5))
    P = rng.normal(size=2)                      # one column for every mapped call
    Us = rng.normal(size=(2, 20))
    got = BufferedFunction(m)(X, P, Us)
    want = [np.asarray(r) for r in m(X, P, Us)]
    assert len(got) == len(want)
    for a, b in zip(got, want):
        assert a.shape == b.shape and np.array_equal(a, b)
    # results are fresh arrays each call: earlier ones are not overwritten
    again = BufferedFunction(m)
    first = again(X, P, Us)[0].copy()
    kept = again(X, P, Us)[0]
    again(2 * X, P, Us)
    assert np.array_equal(kept, first)
    # a wrong shape gets CasADi's own error, not a silent misread
    with pytest.raises(RuntimeError):
        BufferedFunction(m)(X[:, :4], P, Us)
