"""The HST roll step in JAX on the CPU: the measurement behind issue 25's choice of tool (benchmark only).

The same episode as ``fused_reference.py`` (RK4 body with wheel-momentum
coupling, four pyramid wheels with drive limits and the exact motor update,
the filtered PID with conditional integration), written the way JAX wants it:
one step as array expressions over the episode axis (``vmap`` is implicit: every
quantity has a leading axis of P), ``lax.scan`` over the steps, ``jit`` over the
whole episode, float64. It takes the fused loop's arguments from an ``.npz``
file so that it runs in an interpreter of its own: JAX is not a dependency of
the package.

    python bench/bench_engine.py jax               # writes the inputs, runs this with $JAX_PYTHON
    JAX_PYTHON=/path/to/venv-with-jax/bin/python python bench/bench_engine.py jax

Run alone: ``python bench/jax_reference.py INPUTS.npz OUTPUT.npz``; it prints
one line per run (P, the threads XLA may use, compile and run seconds) and
writes the final attitude and rate for the caller to compare with the fused loop.
"""

from __future__ import annotations

import os
import sys
import time


def _episode_fn(jnp, lax, a):
    """A function (q0 (P, 4), kp, ki, kd, af (P, 3)) -> final (q, w), jit-able; ``a``: the shared arrays."""
    dt, u_max, n_steps = float(a["dt"]), float(a["u_max"]), int(a["n_steps"])
    inertia, inertia_inv = jnp.asarray(a["inertia"]), jnp.asarray(a["inertia_inv"])
    alloc, axes, phi_t, gamma = (jnp.asarray(a[k]) for k in ("alloc", "axes", "phi_T", "gamma"))
    j_m, k_b, headroom = float(a["j_m"]), float(a["k_b"]), float(a["headroom"])
    speed_max, v_max = float(a["speed_max"]), float(a["v_max"])
    q_r = jnp.asarray(a["q_r"])

    def deriv(q, w, h, tc, te):
        big_h = w @ inertia.T + h
        rhs = -jnp.cross(w, big_h) + tc + te
        dw = rhs @ inertia_inv.T
        x, y, z, s = q[:, 0], q[:, 1], q[:, 2], q[:, 3]
        wx, wy, wz = w[:, 0], w[:, 1], w[:, 2]
        dq = 0.5 * jnp.stack([wz * y - wy * z + wx * s, -wz * x + wx * z + wy * s,
                              wy * x - wx * y + wz * s, -wx * x - wy * y - wz * z], axis=1)
        return dq, dw, -tc

    def step(carry, _):
        q, w, x, integral, filt, kp, ki, kd, af = carry
        # PID on the quaternion error vector (kernels.error3_row, pid.pid_axis)
        bx, by, bz, bw = q[:, 0], q[:, 1], q[:, 2], q[:, 3]
        rx, ry, rz, rw = -q_r[:, 0], -q_r[:, 1], -q_r[:, 2], q_r[:, 3]
        ex = rw * bx + bw * rx + ry * bz - rz * by
        ey = rw * by + bw * ry + rz * bx - rx * bz
        ez = rw * bz + bw * rz + rx * by - ry * bx
        ew = rw * bw - rx * bx - ry * by - rz * bz
        sign = jnp.where(ew < 0.0, 1.0, -1.0)
        e = jnp.stack([ex, ey, ez], axis=1) * sign[:, None]
        deriv_term = (1.0 - af) / dt * (e - filt)
        raw = kp * e + ki * (integral + 0.5 * e * dt) + kd * deriv_term
        u = jnp.clip(raw, -u_max, u_max)
        integral = jnp.where((u != raw) & (e * raw > 0.0), integral, integral + e * dt)
        filt = af * filt + (1.0 - af) * e
        # wheels: allocation, drive limits, exact motor step, mean torque on the body
        speed = x[:, :, 2]
        v = -(u @ alloc.T)
        emf = k_b * speed
        v = jnp.clip(v, emf - headroom, emf + headroom)
        v = jnp.where((jnp.abs(speed) >= speed_max) & ((v - emf) * speed > 0.0), emf, v)
        v = jnp.clip(v, -v_max, v_max)
        xn = x @ phi_t + v[:, :, None] * gamma
        h = (speed * j_m) @ axes.T
        tc = -((xn[:, :, 2] * j_m) @ axes.T - h) / dt
        # RK4 body over the held interval, then the renormalisation
        te = jnp.zeros_like(tc)
        k1 = deriv(q, w, h, tc, te)
        k2 = deriv(q + 0.5 * dt * k1[0], w + 0.5 * dt * k1[1], h + 0.5 * dt * k1[2], tc, te)
        k3 = deriv(q + 0.5 * dt * k2[0], w + 0.5 * dt * k2[1], h + 0.5 * dt * k2[2], tc, te)
        k4 = deriv(q + dt * k3[0], w + dt * k3[1], h + dt * k3[2], tc, te)
        q = q + dt / 6.0 * (k1[0] + 2.0 * (k2[0] + k3[0]) + k4[0])
        w = w + dt / 6.0 * (k1[1] + 2.0 * (k2[1] + k3[1]) + k4[1])
        q = q / jnp.sqrt(jnp.sum(q * q, axis=1, keepdims=True))
        return (q, w, xn, integral, filt, kp, ki, kd, af), None

    def episode(q0, kp, ki, kd, af):
        P = q0.shape[0]
        z3 = jnp.zeros((P, 3))
        carry = (q0, z3, jnp.zeros((P, alloc.shape[0], 3)), z3, z3, kp, ki, kd, af)
        carry, _ = lax.scan(step, carry, None, length=n_steps)
        return carry[0], carry[1]

    return episode


def main(inputs: str, output: str) -> None:
    threads = os.environ.get("JAX_REFERENCE_THREADS", "")
    os.environ["JAX_ENABLE_X64"] = "1"
    import jax
    import jax.numpy as jnp
    import numpy as np
    from jax import lax

    jax.config.update("jax_enable_x64", True)
    a = dict(np.load(inputs))
    fn = jax.jit(_episode_fn(jnp, lax, a))
    args = [jnp.asarray(a[k]) for k in ("q0", "kp", "ki", "kd", "af")]
    t0 = time.perf_counter()
    q, w = fn(*args)
    q.block_until_ready()
    compile_s = time.perf_counter() - t0
    best = float("inf")
    for _ in range(int(a["reps"])):
        t0 = time.perf_counter()
        q, w = fn(*args)
        q.block_until_ready()
        best = min(best, time.perf_counter() - t0)
    np.savez(output, q=np.asarray(q), w=np.asarray(w), run_s=best, compile_s=compile_s)
    print(f"jax {jax.__version__}: P={args[0].shape[0]} threads={threads or 'all'} compile+run {compile_s:.2f} s, "
          f"run {best:.3f} s")


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2])
