"""An independent numpy/scipy implementation of the contract's base physics, written from
CONTRACT.md §1 without any greybox code, to check the CasADi model against."""
import numpy as np
from scipy.integrate import solve_ivp


def rotors(layout, l):
    if layout == "plus":
        return np.array([[l, 0, 0], [0, l, 0], [-l, 0, 0], [0, -l, 0]]), np.array([-1, 1, -1, 1])
    a = l / np.sqrt(2)
    return np.array([[a, a, 0], [-a, -a, 0], [a, -a, 0], [-a, a, 0]]), np.array([1, 1, -1, -1])


def rot(phi, th, psi):
    Rx = np.array([[1, 0, 0], [0, np.cos(phi), -np.sin(phi)], [0, np.sin(phi), np.cos(phi)]])
    Ry = np.array([[np.cos(th), 0, np.sin(th)], [0, 1, 0], [-np.sin(th), 0, np.cos(th)]])
    Rz = np.array([[np.cos(psi), -np.sin(psi), 0], [np.sin(psi), np.cos(psi), 0], [0, 0, 1]])
    return Rz @ Ry @ Rx


def rhs(s, w, m, J, g, KT, b, Kd, Jr, pos, spin):
    phi, th, psi = s[3:6]
    v = s[6:9]
    om = s[9:12]
    R = rot(phi, th, psi)
    T = KT * w ** 2
    F = R @ np.array([0, 0, -T.sum()]) - Kd * v
    acc = np.array([0, 0, g]) + F / m
    tau = np.zeros(3)
    for i in range(4):
        tau += np.cross(pos[i], [0, 0, -T[i]])
        tau[2] += spin[i] * b * w[i] ** 2
    Om = np.dot(spin, w)
    h = np.array([0, 0, -Jr * Om])          # rotor angular momentum
    tau += -np.cross(om, h)                  # gyroscopic torque on the body
    omd = np.linalg.solve(J, tau - np.cross(om, J @ om))
    # Euler rates by solving omega = E(phi, theta) * euler_dot (rather than copying W)
    E = np.array([[1, 0, -np.sin(th)],
                  [0, np.cos(phi), np.sin(phi) * np.cos(th)],
                  [0, -np.sin(phi), np.cos(phi) * np.cos(th)]])
    ed = np.linalg.solve(E, om)
    return np.concatenate([v, ed, acc, omd])


def simulate(t, W, layout, l, m, J, g, KT, b, Kd, Jr, x0=None):
    pos, spin = rotors(layout, l)
    x = np.zeros(12) if x0 is None else np.array(x0, float)
    out = [x]
    for k in range(len(t) - 1):
        sol = solve_ivp(lambda _t, s: rhs(s, W[k], m, J, g, KT, b, np.asarray(Kd), Jr, pos, spin),
                        (t[k], t[k + 1]), x, method="DOP853", rtol=1e-11, atol=1e-12)
        x = sol.y[:, -1]
        out.append(x)
    return np.array(out)
