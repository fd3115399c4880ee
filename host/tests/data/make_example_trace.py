#!/usr/bin/env python3
"""Writes example_trace.csv: a short analytic input trace with ground truth.

Paper motor (Rs = 5 ohm, Ls = 8.5 mH, psi_f = 0.16 Wb, pole pitch 0.015 m) in
steady state at v = 0.3 m/s (10 Hz electrical), i_d = 0, i_q = 1 A, sampled at
10 kHz. Stationary-frame voltage equation (amplitude-invariant):
    u = Rs i + Ls di/dt + omega_e psi_f [-sin theta, cos theta]
Usage: python3 make_example_trace.py > example_trace.csv
"""
import math

RS, LS, PSI_F, TAU = 5.0, 0.0085, 0.16, 0.015
V, IQ, TS, N = 0.3, 1.0, 1e-4, 20
W = math.pi * V / TAU

print("# Example input trace (see make_example_trace.py): paper motor,")
print("# steady state at 0.3 m/s (10 Hz electrical), i_q = 1 A, Ts = 100 us.")
print("t,u_alpha,u_beta,i_alpha,i_beta,theta,v,x")
for k in range(N):
    t = k * TS
    th = W * t
    i_a, i_b = -IQ * math.sin(th), IQ * math.cos(th)
    di_a, di_b = -IQ * W * math.cos(th), -IQ * W * math.sin(th)
    u_a = RS * i_a + LS * di_a - W * PSI_F * math.sin(th)
    u_b = RS * i_b + LS * di_b + W * PSI_F * math.cos(th)
    print(f"{t:.4f},{u_a:.9g},{u_b:.9g},{i_a:.9g},{i_b:.9g},{th:.9g},{V:.9g},{V * t:.9g}")
