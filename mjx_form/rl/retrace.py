"""Retrace(lambda) targets for Q(x_t, a_t) along one sequence (Munos et al., 2016).

Time index t = 0..T-1 of an unroll; batch with `jax.vmap`. With truncated traces
c_t = lambda * min(1, pi(a_t|x_t) / mu(a_t|x_t)), the target G_t obeys

  G_{T-1} = r_{T-1} + discount_{T-1} V(x_T)
  G_t     = r_t + discount_t (V(x_{t+1}) + c_{t+1} (G_{t+1} - Q(x_{t+1}, a_{t+1})))

where V(x) = E_{a~pi} Q(x, a). A discount of 0 (terminal state, or an episode boundary inside
the unroll) cuts the trace there, so no return leaks across episodes.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp


def importance_weights(log_rhos: jax.Array, lambda_: float = 1.0) -> jax.Array:
  """Truncated traces c = lambda_ * min(1, exp(log_rhos)), same shape as `log_rhos`."""
  return lambda_ * jnp.exp(jnp.minimum(log_rhos, 0.0))


def retrace_targets(q_t: jax.Array, v_tp1: jax.Array, rewards: jax.Array, discounts: jax.Array,
                    log_rhos: jax.Array, lambda_: float = 1.0,
                    unroll: int | bool = 1) -> jax.Array:
  """Retrace targets for one sequence; all inputs [T], returns [T] (no gradient flows back).

  `unroll` is the backward recursion's `lax.scan` unroll (True: straight-line code, no loop);
  it changes how the targets are computed on the device, not their values.

  q_t[t]:       Q_target(x_t, a_t) (q_t[0] is not used).
  v_tp1[t]:     E_{a~pi} Q_target(x_{t+1}, a).
  rewards[t]:   r_t, received on the step x_t -> x_{t+1}.
  discounts[t]: gamma * d_t, d_t = 0 where x_{t+1} is terminal or not x_t's successor, else 1.
  log_rhos[t]:  log pi(a_t|x_t) - log mu(a_t|x_t) (log_rhos[0] is not used).
  """
  q_t, v_tp1, rewards, discounts, log_rhos = jax.lax.stop_gradient(
      jnp.broadcast_arrays(q_t, v_tp1, rewards, discounts, log_rhos))
  dtype = jnp.result_type(q_t, v_tp1, rewards, discounts)
  c = importance_weights(log_rhos, lambda_).astype(dtype)
  # Step t needs c[t+1] and q_t[t+1]; the last step has no successor, so its trace is 0.
  c_next = jnp.concatenate([c[1:], jnp.zeros_like(c[:1])])
  q_next = jnp.concatenate([q_t[1:], jnp.zeros_like(q_t[:1])]).astype(dtype)

  def step(g_next, xs):
    r, discount, v, c, q = xs
    g = r + discount * (v + c * (g_next - q))
    return g, g

  xs = (rewards.astype(dtype), discounts.astype(dtype), v_tp1.astype(dtype), c_next, q_next)
  _, targets = jax.lax.scan(step, jnp.zeros((), dtype), xs, reverse=True, unroll=unroll)
  return targets
