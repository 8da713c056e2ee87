"""The MPO policy loss (Abdolmaleki et al., 2018) for a diagonal Gaussian policy, with the
decoupled mean / scale KL constraints of Acme's `mpo` agent (per action dimension by default).

Shapes: N sampled actions per state, S states (a flattened batch), A action dimensions.

One scalar loss trains all three parameter groups; stop-gradients route each term:
  temperature  eta   <- eta * epsilon + eta * mean_s log mean_i exp(sg(Q) / eta)  (E-step dual)
  policy (online)    <- -mean_s sum_i w_i [log N(a_i; mu, sg(sigma_target))
                                          + log N(a_i; sg(mu_target), sigma)]   (M-step)
                        + sum sg(alpha_mean) * KL_mean + sum sg(alpha_scale) * KL_scale
  alphas             <- sum alpha_mean * (epsilon_mean - sg(KL_mean))
                        + sum alpha_scale * (epsilon_scale - sg(KL_scale))
with E-step weights w = sg(softmax_i(Q / eta)), KL_mean = mean_s KL(target || N(mu, sigma_target))
and KL_scale = mean_s KL(target || N(mu_target, sigma)), both [A] with per-dimension constraints
(else summed over A, scalars). `target`, `sampled_actions` and `q_values` are constants.

Action penalty (optional, `MPOConfig.action_penalty`; on by default in Acme's MPO, which
recommends it for the control suite; the paper does not say): a second objective, the cost
c_i = -||a_i - clip(a_i, -1, 1)|| (the bounds [-1, 1], every task's control range but
quadruped's, `Task.action_bounds`), gets its own E-step with temperature eta_p and bound
epsilon_penalty (multi-objective MPO, Abdolmaleki et al., 2020); its weights are added to w and
its dual loss to the temperature's. Without it a Gaussian policy whose actions are clipped by
the environment can drift its mean far outside [-1, 1], where every sample saturates: the
policy is then bang-bang and explores little (as hopper_stand's policy did: README).
`MPOConfig.clip_mean_targets` (optional) fits the mean to samples clipped to the bounds
widened by a scale instead.
"""

from __future__ import annotations

import dataclasses
import math
from typing import NamedTuple

import jax
import jax.numpy as jnp

from mjx_form.rl.distributions import DiagonalGaussian

DUAL_EPSILON = 1e-8  # dual value = softplus(raw) + DUAL_EPSILON, as in Acme
MIN_RAW_DUAL = -18.0  # `clip_duals` floor for the raw duals, as in Acme


@dataclasses.dataclass(frozen=True)
class MPOConfig:
  """KL bounds and initial raw duals.

  The initial raw duals match Acme's TF/JAX learner defaults (1, 1, 10: softplus gives
  temperature 1.31, alpha_mean 1.31, alpha_scale 10.0). Acme's bounds there are epsilon 0.1,
  epsilon_mean 1e-3, epsilon_stddev 1e-6 (its newer GaussianPolicyLossConfig: 0.1, 2.5e-3,
  1e-6 with raw duals 10, 10, 1000). With per-dimension constraints every action dimension
  gets the full epsilon_mean / epsilon_scale, so the total KL bound grows with A.
  """

  epsilon: float = 0.1  # KL(E-step policy || target policy) bound, for the temperature
  epsilon_mean: float = 0.005  # KL bound on the mean-only change (per dimension if per_dim)
  epsilon_scale: float = 1e-5  # KL bound on the scale-only change (per dimension if per_dim)
  per_dim_constraining: bool = True
  init_log_temperature: float = 1.0
  init_log_alpha_mean: float = 1.0
  init_log_alpha_scale: float = 10.0
  action_penalty: bool = False  # the MO-MPO penalty on sampled actions outside [-1, 1]
  # (a population member's traced bool where members differ: its duals then always hold the
  # penalty's, `init_duals` with it True)
  epsilon_penalty: float = 1e-3  # its KL bound (Acme's default); its dual starts as eta's
  # The M-step fits the mean to the sampled actions clipped to [-1 - s, 1 + s], s the target's
  # scale: where samples lie beyond a bound the environment applies the bound (and a clipping
  # critic values them alike); fitted to the raw samples, those beyond a bound that is best
  # pull the mean further out, until every sample lies beyond it and the E-step's weights
  # cannot tell them apart (benchmarks/saturation_bandit.py). Fitted to the clipped samples,
  # the mean stays within about a scale of the bound, where the samples straddle it and the
  # weights see both sides. The scale's margin keeps the mean at or past a bound that is best
  # (clipped at the bound itself, the mean would settle inside it: 0.93 for 1 on the bandit).
  # The scale is fitted to the raw samples (their spread about the target's mean). Off: the
  # paper's M-step.
  clip_mean_targets: bool = False  # (a population member's traced bool where members differ)


class MPODuals(NamedTuple):
  """Raw (unconstrained) Lagrange multipliers; values are softplus(raw) + DUAL_EPSILON."""

  log_temperature: jax.Array  # []
  log_alpha_mean: jax.Array  # [A], or [] without per-dimension constraints
  log_alpha_scale: jax.Array  # [A], or [] without per-dimension constraints
  log_penalty_temperature: jax.Array | None = None  # [] with the action penalty, else absent


def init_duals(config: MPOConfig, action_size: int, dtype=jnp.float32) -> MPODuals:
  """Initial raw duals from `config`."""
  shape = (action_size,) if config.per_dim_constraining else ()
  return MPODuals(
      log_temperature=jnp.full((), config.init_log_temperature, dtype),
      log_alpha_mean=jnp.full(shape, config.init_log_alpha_mean, dtype),
      log_alpha_scale=jnp.full(shape, config.init_log_alpha_scale, dtype),
      log_penalty_temperature=(jnp.full((), config.init_log_temperature, dtype)
                               if config.action_penalty else None))


def dual_value(raw: jax.Array) -> jax.Array:
  """The positive multiplier of a raw dual: softplus(raw) + DUAL_EPSILON."""
  return jax.nn.softplus(raw) + DUAL_EPSILON


def clip_duals(duals: MPODuals) -> MPODuals:
  """Keeps raw duals >= MIN_RAW_DUAL after an update, so softplus keeps a usable gradient."""
  return jax.tree.map(lambda x: jnp.maximum(x, MIN_RAW_DUAL), duals)


def e_step_weights(q_values: jax.Array, temperature: jax.Array) -> jax.Array:
  """Non-parametric policy weights softmax_i(Q / eta) over the samples: [N, S] -> [N, S]."""
  return jax.nn.softmax(q_values / temperature, axis=0)


def temperature_loss(q_values: jax.Array, temperature: jax.Array, epsilon: float) -> jax.Array:
  """E-step dual eta * epsilon + eta * mean_s log mean_i exp(Q / eta); q_values [N, S].

  Written as max_i Q + eta * log mean_i exp((Q - max_i Q) / eta) (equal), whose gradient in eta
  does not cancel two terms of size max|Q| / eta when the temperature is small.
  """
  q_max = jax.lax.stop_gradient(jnp.max(q_values, axis=0))  # [S]
  log_mean_exp = (jax.nn.logsumexp((q_values - q_max) / temperature, axis=0)
                  - math.log(q_values.shape[0]))
  return temperature * epsilon + jnp.mean(q_max + temperature * log_mean_exp)


def mpo_loss(duals: MPODuals, online: DiagonalGaussian, target: DiagonalGaussian,
             sampled_actions: jax.Array, q_values: jax.Array,
             config: MPOConfig) -> tuple[jax.Array, dict[str, jax.Array]]:
  """The MPO loss (policy + KL penalties + dual losses) and its metrics.

  online, target: mean/scale [S, A]; sampled_actions [N, S, A] (drawn from `target`);
  q_values [N, S]. Returns (scalar loss, dict of scalar metrics).
  """
  target, sampled_actions, q_values = jax.lax.stop_gradient((target, sampled_actions, q_values))
  num_samples = q_values.shape[0]
  temperature = dual_value(duals.log_temperature)
  alpha_mean = dual_value(duals.log_alpha_mean)
  alpha_scale = dual_value(duals.log_alpha_scale)

  # E-step: weights of the non-parametric policy and the temperature's dual loss.
  weights = jax.lax.stop_gradient(e_step_weights(q_values, temperature))  # [N, S]
  loss_temperature = temperature_loss(q_values, temperature, config.epsilon)
  # KL(E-step policy || uniform over the samples) estimates KL(E-step policy || target).
  kl_nonparametric = _kl_from_uniform(weights)
  ess = 1.0 / jnp.sum(jnp.square(weights), axis=0)  # [S], of the Q weights
  out_of_bounds = sampled_actions - jnp.clip(sampled_actions, -1.0, 1.0)  # [N, S, A]
  penalty_metrics = {}
  on = config.action_penalty  # a Python bool, or a population member's traced one (grid.py)
  if not (isinstance(on, bool) and not on):
    if duals.log_penalty_temperature is None:
      raise ValueError("MPOConfig.action_penalty needs duals from init_duals with it on")
    penalty_temperature = dual_value(duals.log_penalty_temperature)
    cost = -jnp.linalg.norm(out_of_bounds, axis=-1)  # [N, S], 0 inside the bounds
    penalty_weights = jax.lax.stop_gradient(e_step_weights(cost, penalty_temperature))
    # Where a member's flag is off its weights are plain MPO's exactly (w + 0) and so are its
    # loss and gradients (to rounding); its penalty dual gets a zero gradient and stays put.
    loss_temperature += jnp.where(
        on, temperature_loss(cost, penalty_temperature, config.epsilon_penalty), 0.0)
    weights = weights + jnp.where(on, penalty_weights, 0.0)  # each sums to 1; together to 2
    penalty_metrics = {
        "penalty_temperature": jnp.where(on, penalty_temperature, jnp.nan),
        "penalty_kl_nonparametric_rel": jnp.where(
            on, _kl_from_uniform(penalty_weights) / config.epsilon_penalty, jnp.nan)}

  # M-step: weighted maximum likelihood of the two decoupled distributions.
  fixed_scale = DiagonalGaussian(online.mean, target.scale)  # learns the mean
  fixed_mean = DiagonalGaussian(target.mean, online.scale)  # learns the scale
  bound = 1.0 + target.scale  # [S, A]: the bounds widened by one scale (MPOConfig)
  mean_targets = jnp.where(config.clip_mean_targets,
                           jnp.clip(sampled_actions, -bound, bound), sampled_actions)  # [N, S, A]
  loss_policy_mean = -jnp.mean(jnp.sum(weights * fixed_scale.log_prob(mean_targets), axis=0))
  loss_policy_scale = -jnp.mean(jnp.sum(weights * fixed_mean.log_prob(sampled_actions), axis=0))

  # Trust region KL(target || decoupled online): [A] per dimension, else [].
  per_dim = config.per_dim_constraining
  kl_mean = jnp.mean(target.kl_divergence(fixed_scale, per_dim=per_dim), axis=0)
  kl_scale = jnp.mean(target.kl_divergence(fixed_mean, per_dim=per_dim), axis=0)
  sg = jax.lax.stop_gradient
  loss_kl = jnp.sum(sg(alpha_mean) * kl_mean) + jnp.sum(sg(alpha_scale) * kl_scale)
  loss_alpha = (jnp.sum(alpha_mean * (config.epsilon_mean - sg(kl_mean)))
                + jnp.sum(alpha_scale * (config.epsilon_scale - sg(kl_scale))))

  loss_policy = loss_policy_mean + loss_policy_scale
  loss = loss_policy + loss_kl + loss_alpha + loss_temperature

  metrics = {
      "loss_policy": loss_policy,
      "loss_kl": loss_kl,
      "loss_alpha": loss_alpha,
      "loss_temperature": loss_temperature,
      "temperature": temperature,
      "alpha_mean": jnp.mean(alpha_mean),
      "alpha_scale": jnp.mean(alpha_scale),
      "kl_mean": jnp.sum(kl_mean),  # mean over states, summed over dimensions
      "kl_scale": jnp.sum(kl_scale),
      "kl_mean_rel": jnp.mean(kl_mean) / config.epsilon_mean,  # > 1: constraint violated
      "kl_scale_rel": jnp.mean(kl_scale) / config.epsilon_scale,
      "kl_nonparametric_rel": kl_nonparametric / config.epsilon,
      "ess_fraction": jnp.mean(ess) / num_samples,  # 1: uniform weights, 1/N: one sample
      "q_mean": jnp.mean(q_values),
      "q_max": jnp.mean(jnp.max(q_values, axis=0)),
      "scale_mean": jnp.mean(online.scale),
      "entropy": jnp.mean(online.entropy()),
      # Saturation: parts of sampled actions, and of the policy's mean, outside [-1, 1] (the
      # control range of every task but quadruped's, whose lift actuators go to 1.1 and
      # extenders to 0.8: there these shares are of [-1, 1], not of what MuJoCo clamps).
      "sampled_out_of_bounds": jnp.mean(out_of_bounds != 0),
      "mean_out_of_bounds": jnp.mean(jnp.abs(online.mean) > 1.0),
      **penalty_metrics,
  }
  return loss, metrics


def _kl_from_uniform(weights: jax.Array) -> jax.Array:
  """mean_s KL(weights[:, s] || uniform over the N samples); weights [N, S] sum to 1 over N."""
  num_samples = weights.shape[0]
  return jnp.mean(jnp.sum(weights * jnp.log(num_samples * weights + 1e-30), axis=0))
