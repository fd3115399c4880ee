#!/usr/bin/env python3
"""DC steps in the DCFO: what structural extensions of the observer could buy.

Continuous-time linear model of one observer, time in 1/w (w = the flux's electrical
frequency, the notch exactly at it unless stated), flux amplitude 1, complex alpha-beta:

    z'  = e + K d - du_hat        e = j psi + du   (the back-EMF; du the DC step)
    x1' = k (z - x1) - x2,  x2' = x1,  d = z - x1,  psi_hat = x1   (SOGI, k = 2 zeta)

K = eta (the paper's h) unless an extension says otherwise. The paper motor at 10 Hz:
+2 V is 0.199 of the back-EMF; +0.2 A is -0.1 of it (Rs 0.2 A) with a flux step of
-0.0106 (Ls 0.2 A). The figures are the largest angle error (deg) over 16 phases of
the step. Standard library only; about a minute. See docs/dc-step-analysis.md.
"""
import cmath
import math

DU_2V, DU_02A, DPSI_02A = 0.199, 0.1, 0.0106


def simulate(zeta, eta, du, phase, dpsi=0.0, ext=None, g=0.0, w_true=1.0, w_hat=1.0,
             switch=None, t_end=40.0, dt=0.002):
    """Largest angle error (deg) after a step of `du` (and flux `dpsi`) at `phase`.

    ext: None, 'pi' (K = a + b/s on d, with a = eta - g, b = g eta), 'rot' (du_hat' =
    g (e - du_hat - j w_hat psi_hat)), 'rot_d' (the same projected on the flux),
    'diff_d' (residual e - du_hat - psi_hat', projected on the flux).
    switch: (t, zeta2, eta2): the tuning from t after the step on.
    """
    z, x1, x2, dh, q = 1.0 + 0j, 1.0 + 0j, -1j, 0j, 0j
    t, th, worst, t0, stepped = 0.0, 0.0, 0.0, 4 * math.pi, False
    while t < t0 + t_end:
        if not stepped and t >= t0:
            stepped = True
            z += dpsi * 1j * cmath.exp(1j * phase)
        zt, et = zeta, eta
        if switch and stepped and t - t0 >= switch[0]:
            zt, et = switch[1], switch[2]
        k = 2 * zt
        psi = cmath.exp(1j * th)
        e = 1j * w_true * psi + (du * cmath.exp(1j * phase) if stepped else 0)
        d = z - x1
        if ext == 'pi':
            dz = e + (et - g) * d + g * et * q
        else:
            dz = e + et * d - dh
        dx1 = k * (z - x1) - x2
        dx2 = x1
        if ext in ('rot', 'rot_d'):
            r = e - dh - 1j * w_hat * x1
        elif ext == 'diff_d':
            r = e - dh - dx1
        else:
            r = 0
        if ext in ('rot_d', 'diff_d'):
            u = x1 / abs(x1)
            r = (r * u.conjugate()).real * u
        z += dz * dt
        x1 += dx1 * dt
        x2 += dx2 * dt
        dh += g * r * dt
        q += d * dt
        t += dt
        th += w_true * dt
        if stepped:
            worst = max(worst, abs(cmath.phase(x1 / cmath.exp(1j * th))))
    return math.degrees(worst)


def worst(zeta, eta, du, dpsi=0.0, **kw):
    return max(simulate(zeta, eta, du, i * math.pi / 8, dpsi, **kw) for i in range(16))


def pair(zeta, eta, **kw):
    return worst(zeta, eta, DU_2V, **kw), worst(zeta, eta, DU_02A, -DPSI_02A, **kw)


def roots(c):
    """Roots of the monic polynomial c (highest power first), Durand-Kerner."""
    n = len(c) - 1
    r = [(0.4 + 0.9j) ** i for i in range(n)]
    for _ in range(500):
        r = [r[i] - sum(c[k] * r[i] ** (n - k) for k in range(n + 1))
             / math.prod(r[i] - r[j] for j in range(n) if j != i) for i in range(n)]
    return r


def pi_extension(zeta, a, b):
    """K = a + b/s: psi_hat / psi = 2 zeta s^3 / Q(s), Q = s^4 + (2 zeta - a) s^3 +
    (1 - b) s^2 - a s - b. Phase slope at w (rad per relative frequency error) is
    (1 + b) / zeta; returns (slope, least damping, largest |H|, its frequency)."""
    q = [1, 2 * zeta - a, 1 - b, -a, -b]
    damping = min(-x.real / abs(x) for x in roots(q) if abs(x) > 1e-9)
    h = lambda s: abs(2 * zeta * s ** 3 / sum(c * s ** (4 - i) for i, c in enumerate(q)))
    peak = max((h(1j * f / 100), f / 100) for f in range(1, 2000))
    return (1 + b) / zeta, damping, peak[0], peak[1]


def magnitude_step(p, c, du, phase, dpsi=0.0, zeta=1.0, eta=-0.2, a=0.1, zb=1.0,
                   w_true=1.0, t_end=20.0, dt=0.001, settle=None):
    """Section 5: the DCFO with the radial feedback of gain p on the squared magnitude's
    deviation from its mean (rate a), and the angle turned back by c times the
    magnitude's rate over w |psi_hat|, read through a band-pass at w of damping zb.
    A step of `du` and a flux step `dpsi` on one axis (at `phase`), the notch at 1;
    returns the largest angle error (deg) after the step, or with `settle` (no step) the
    largest over the last `settle` time units."""
    z, x1, x2 = 1.0 + 0j, 1.0 + 0j, -1j
    s2, b1, b2 = 1.0, 0.0, 0.0
    t, th, worst, stepped = 0.0, 0.0, 0.0, False
    t0 = 0.0 if settle else 4 * math.pi
    k = 2 * zeta
    direction = cmath.exp(1j * phase)
    while t < t0 + t_end:
        if not stepped and t >= t0 and not settle:
            stepped = True
            z += dpsi * direction
        e = 1j * w_true * cmath.exp(1j * th) + (du * direction if stepped else 0)
        m2 = abs(x1) ** 2
        dz = e + eta * (z - x1) - p * (m2 - s2) / (2 * s2) * x1
        dx1 = k * (z - x1) - x2
        rate = (dx1 * x1.conjugate()).real / m2
        b1 += (2 * zb * (rate - b1) - b2) * dt
        b2 += b1 * dt
        z += dz * dt
        x1 += dx1 * dt
        x2 += x1 * dt
        s2 += a * (m2 - s2) * dt
        t += dt
        th += w_true * dt
        if (stepped or settle) and (not settle or t > t_end - settle):
            worst = max(worst, abs(cmath.phase(x1 / cmath.exp(1j * th)) - c * b1))
    return math.degrees(worst)


def main():
    print("1. The observer as built, notch at the true frequency: +2 V / +0.2 A (deg)")
    for zeta, eta in [(1.0, -0.2), (0.7, -0.2), (0.5, -0.3)]:
        print("   zeta %.1f eta %.1f: %5.2f / %5.2f" % ((zeta, eta) + pair(zeta, eta)))

    print("2. An integral term on d, K = (eta - g) + g eta / s (zeta 1.0, eta -0.2)")
    for g in [0.0, 0.5, 1.0, 2.0]:
        a, b = -0.2 - g, -0.2 * g
        slope, damping, peak, at = pi_extension(1.0, a, b)
        u, i = pair(1.0, -0.2, ext='pi', g=g)
        print("   g %.1f: +2 V %5.2f, +0.2 A %5.2f; phase slope %.2f, least damping %.2f,"
              " |H| peak %.2f at %.2f w" % (g, u, i, slope, damping, peak, at))
    print("   b = -1 (phase slope zero) is never stable: Routh needs "
          "(2z - a)(1 - b)(-a) > a^2 + (2z - a)^2 (-b), i.e. 0 > 4 zeta^2 at b = -1")

    print("3. A DC-voltage estimator on the back-EMF residual, rate g w (deg; then the"
          " angle error with the notch and the residual's speed 10 % below the mover)")
    for ext in ['rot', 'rot_d', 'diff_d']:
        for zeta, eta in [(1.0, -0.2), (0.5, -0.3)]:
            for g in [0.25, 0.5, 1.0]:
                u, i = pair(zeta, eta, ext=ext, g=g)
                s = simulate(zeta, eta, 0.0, 0.0, ext=ext, g=g, w_true=1.1, t_end=60)
                base = simulate(zeta, eta, 0.0, 0.0, w_true=1.1, t_end=60)
                print("   %-6s zeta %.1f g %.2f: +2 V %6.2f, +0.2 A %6.2f; notch 10 %% off"
                      " %6.2f (%.2f without)" % (ext, zeta, g, u, i, s, base))

    print("4. zeta 1.0 / eta -0.2, switched to 0.5 / -0.3 some time after the step")
    for frac in [0.0, 0.1, 0.15, 0.2, 0.3]:
        sw = (frac * 2 * math.pi, 0.5, -0.3)
        print("   at %.2f periods: +2 V %5.2f, +0.2 A %5.2f" % ((frac,) + pair(1.0, -0.2, switch=sw)))

    print("5. The magnitude feedback p and the offset's angle c (zeta 1.0, eta -0.2; +0.2 A"
          " as -0.0995 of the back-EMF and a -0.0106 flux step on the same axis; then the"
          " angle error with the mover 10 % off the notch, either way)")
    for p, c in [(0.0, 0.0), (1.0, 0.0), (0.0, 0.7), (1.0, 0.7), (1.0, 1.0)]:
        u = max(magnitude_step(p, c, DU_2V, i * math.pi / 8) for i in range(16))
        i_ = max(magnitude_step(p, c, -DU_02A, i * math.pi / 8, -DPSI_02A) for i in range(16))
        off = [magnitude_step(p, c, 0.0, 0.0, w_true=w, t_end=80, settle=10) for w in (0.9, 1.1)]
        print("   p %.1f c %.1f: +2 V %5.2f, +0.2 A %5.2f; notch 10 %% off %.2f / %.2f"
              % (p, c, u, i_, off[0], off[1]))


if __name__ == "__main__":
    main()
