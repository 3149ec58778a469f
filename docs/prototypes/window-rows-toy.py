"""Toy of the carry's level-tilt problem: one tilt θ, one difference bias b, the yaw flexure
(3rd-order Gauss-Markov θ_f, θ̇_f, θ̈_f) seen through a lever arm L in the horizontal df row,
and the yaw rate row. Truth: slave IMU interval means at 100 Hz (Δθ/dt, L Δθ̇/dt), interpolated
at 50 Hz master epochs on the grid (a 2-interval window centred on the epoch, windows tile).
Filter A: point-sample model at the epoch (what the flight filter does).
Filter B: window-mean model (state at the window's end, the window start's θ_f, θ̇_f cloned);
C: window mean from the back-propagated state, no cross-covariance; D: delayed-state rows
(Brown & Hwang), the cross-covariance carried through the sequential rows, no clone.
B and D:
exact for the truth.  Prints RMS and σ of θ (mrad) over the carry.
Usage: python3 toy.py [SEED [LEVER_ARM_M [MASTER_EVERY_K_IMU_STEPS]]] (defaults 1, 4.5, 2)."""
import numpy as np, sys

def expm(a):
    n = np.linalg.norm(a, 1); s = max(0, int(np.ceil(np.log2(n))) + 1) if n > 0 else 0
    a = a / 2**s; e = np.eye(len(a)); t = np.eye(len(a))
    for k in range(1, 20):
        t = t @ a / k; e = e + t
    for _ in range(s): e = e @ e
    return e

def disc(f, qc, dt):
    n = len(f); m = np.zeros((2*n, 2*n)); m[:n, :n] = -f; m[:n, n:] = qc; m[n:, n:] = f.T
    e = expm(m * dt); phi = e[n:, n:].T; return phi, phi @ e[:n, n:]

rng = np.random.default_rng(int(sys.argv[1]) if len(sys.argv) > 1 else 1)
runs, T_end = 200, 77.0
g, L = 9.81, float(sys.argv[2]) if len(sys.argv) > 2 else 4.5
sig_f, tau = np.radians(0.1), 0.3212
beta = 2.904629975029914 / tau; q = 16/3 * beta**5 * sig_f**2
dt, k_master = 0.01, int(sys.argv[3]) if len(sys.argv) > 3 else 2  # master every k IMU steps
sig_th, sig_b = 8.7e-3, 1.0e-3
r_acc, r_rate = 1.0e-3, 1.0e-4          # design (floors)
n_acc_s, n_acc_m, n_rate = 4.9e-4, 6.9e-4, 3e-5  # truth: slave / master accel, slave gyro
F = np.array([[0, 1, 0], [0, 0, 1], [-beta**3, -3*beta**2, -3*beta]]); Qc = np.zeros((3, 3)); Qc[2, 2] = q
phi3, q3 = disc(F, Qc, dt)
b2 = beta**2; P3 = np.array([[sig_f**2, 0, -b2*sig_f**2/3], [0, b2*sig_f**2/3, 0], [-b2*sig_f**2/3, 0, b2*b2*sig_f**2]])
nsteps = int(T_end / dt)
# truth
th = rng.normal(0, sig_th, runs); bb = rng.normal(0, sig_b, runs)
fx = rng.multivariate_normal(np.zeros(3), P3, runs)   # (runs, 3)
cq = np.linalg.cholesky(q3 + 1e-30*np.eye(3))
xs = [fx]
for k in range(nsteps + 1):
    fx = fx @ phi3.T + rng.normal(size=(runs, 3)) @ cq.T; xs.append(fx)
xs = np.array(xs)   # (nsteps+2, runs, 3) at t = k dt
acc_mean = L * (xs[1:, :, 1] - xs[:-1, :, 1]) / dt + rng.normal(0, n_acc_s, (nsteps+1, runs))  # interval k: (k-1, k]
rate_mean = (xs[1:, :, 0] - xs[:-1, :, 0]) / dt + rng.normal(0, n_rate, (nsteps+1, runs))
# full filter models: state [θ, b, θ_f, θ̇, θ̈] (+ clones [θ_f, θ̇] for B)
def phi_full(nc):
    n = 5 + nc; p = np.eye(n); p[2:5, 2:5] = phi3; qq = np.zeros((n, n)); qq[2:5, 2:5] = q3; return p, qq
def run(kind):
    nc = 2 if kind == 'B' else 0; n = 5 + nc
    ph, qq = phi_full(nc)
    P = np.zeros((n, n)); P[0, 0] = sig_th**2; P[1, 1] = sig_b**2; P[2:5, 2:5] = P3
    x = np.zeros((runs, n)); have_clone = False; out = []
    for k in range(1, nsteps):
        x = x @ ph.T; P = ph @ P @ ph.T + qq
        if kind == 'A':
            fuse = (k % k_master == 0) and k + 1 <= nsteps   # epoch t = k dt, window (k-1, k+1]
            if fuse:
                za = g*th + bb + 0.5*(acc_mean[k] + acc_mean[k+1]) + rng.normal(0, n_acc_m, runs)
                zr = 0.5*(rate_mean[k] + rate_mean[k+1])
                rows = [(np.array([g, 1, 0, 0, L]), za, r_acc**2), (np.array([0, 0, 0, 1, 0.]), zr, r_rate**2)]
        else:
            fuse = (k % k_master == 1)   # state at window end t = (m+1) dt for the epoch m dt
            if fuse and have_clone:
                W = (k - kc) * dt
                za = g*th + bb + np.mean(acc_mean[kc+1:k+1], axis=0) + rng.normal(0, n_acc_m, runs)
                zr = np.mean(rate_mean[kc+1:k+1], axis=0)
                ha = np.array([g, 1, 0, L/W, 0, 0, -L/W]); hr = np.array([0, 0, 1/W, 0, 0, -1/W, 0])
                rows = [(ha, za, r_acc**2), (hr, zr, r_rate**2)]
            elif fuse:
                rows = []
        if fuse:
            for h, z, r in rows:
                s = h @ P @ h + r; kk = P @ h / s
                x = x + np.outer(z - x @ h, kk); P = P - np.outer(kk, h @ P)
            if kind == 'B' and fuse:
                # clone θ_f, θ̇ at this (window-end) epoch: start of the next window
                J = np.eye(n); J[5:7, :] = 0; J[5, 2] = 1; J[6, 3] = 1
                x = x @ J.T; P = J @ P @ J.T; have_clone = True; kc = k
            if k % 500 < k_master:
                e = x[:, 0] - th
                out.append((k*dt, np.sqrt(np.mean(e**2))*1e3, np.sqrt(P[0, 0])*1e3))
    return out
for kind in 'AB':
    res = run(kind)
    print(kind, ' '.join(f"{t:.0f}s:{r:.3f}/{s:.3f}" for t, r, s in res[::2]))

def run_bh(cross):
    n = 5; ph, qq = phi_full(0)
    W = k_master * dt
    phW = np.eye(n); qW = np.zeros((n, n))
    for _ in range(k_master):
        phW = ph @ phW; qW = ph @ qW @ ph.T + qq
    phWi = np.linalg.inv(phW)
    P = np.zeros((n, n)); P[0, 0] = sig_th**2; P[1, 1] = sig_b**2; P[2:5, 2:5] = P3
    x = np.zeros((runs, n)); out = []; started = False
    for k in range(1, nsteps):
        x = x @ ph.T; P = ph @ P @ ph.T + qq
        if k % k_master != 1:
            continue
        if not started:
            started = True; continue
        kc = k - k_master
        za = g*th + bb + np.mean(acc_mean[kc+1:k+1], axis=0) + rng.normal(0, n_acc_m, runs)
        zr = np.mean(rate_mean[kc+1:k+1], axis=0)
        # z = H x_k + B x_{k-W} + v
        Ha = np.array([g, 1, 0, L/W, 0.]); Ba = np.array([0, 0, 0, -L/W, 0.])
        Hr = np.array([0, 0, 1/W, 0, 0.]); Br = np.array([0, 0, -1/W, 0, 0.])
        rows = []
        for H, B, z, r in [(Ha, Ba, za, r_acc**2), (Hr, Br, zr, r_rate**2)]:
            J = H + B @ phWi
            rows.append([J, B @ phWi, z, r])
        Cs = [-(qW @ (bp)) if cross else np.zeros(n) for (_, bp, _, _) in rows]
        for i, (J, bp, z, r) in enumerate(rows):
            Rp = r + bp @ qW @ bp
            C = Cs[i]
            pj = P @ J + C
            s = J @ P @ J + 2 * J @ C + Rp
            K = pj / s
            x = x + np.outer(z - x @ J, K)
            P = P - np.outer(K, K) * s
            for j in range(i + 1, len(rows)):
                Jj, bpj = rows[j][0], rows[j][1]
                Cs[j] = Cs[j] - K * (J @ Cs[j] + bp @ qW @ bpj) if cross else Cs[j]
        if k % 500 < k_master:
            e = x[:, 0] - th
            out.append((k*dt, np.sqrt(np.mean(e**2))*1e3, np.sqrt(P[0, 0])*1e3))
    return out
for cross, name in [(False, 'C'), (True, 'D')]:
    res = run_bh(cross)
    print(name, ' '.join(f"{t:.0f}s:{r:.3f}/{s:.3f}" for t, r, s in res[::2]))
