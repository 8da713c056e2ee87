"""Behavioural cloning: the policy fitted by maximum likelihood to given actions.

BC (the paper's appendix "BC and BCO"; ../shared/DESIGN.md): the same Gaussian policy network as
the MPO learner's, trained to maximise the mean of log pi(a | x) over pairs (x, a) of
observations and actions, by the learner's policy optimiser (Adam at the learner's learning
rate, 1e-4 by default, gradients clipped at its `max_grad_norm`). The pairs come from a cloning
source (reward_sources.py, `policy_targets`): BC's (mjx_form.imitation.bc) are the
demonstrations' observations with the expert's actions. The critic, its target and the duals
are not trained; the policy's update count and average (where the learner keeps one) advance as
in an MPO update.

`LearnerConfig.cloning_loss` chooses how the Gaussian is fitted:
- "likelihood" (the paper's): minimise -log pi(a | x). Its gradient for the mean is
  (mean - a) / scale^2, so the states where the scale is already small dominate; the scale falls
  first where the expert's action is easy (reacher: ~80% of its transitions at rest) and the mean
  of the rest barely moves (offline on reacher_easy's demonstrations: the mean's squared error
  0.059 -> 0.034 in 20,000 updates, against 0.0035 in 5,000 by squared error; NOTES session 69).
- "decoupled": the mean by squared error, the scale by -log pi(a | x) with the mean held
  (stop-gradient). Per state both losses have the same minimiser (the mean and standard
  deviation of the actions there); a network that cannot fit every state exactly trades the
  states' errors off evenly (least squares) instead of by their predicted variance.
- "squared" (run.py's default): as "decoupled", but the scale's term reaches only the network's
  last layer (the shared layers' features held), so the shared layers fit the mean alone. Offline
  on reacher_easy (benchmarks/cloning_fit.py, NOTES session 70) the return follows how closely
  the mean fits, and the decoupled fit's scale term slowed the mean's fit even weighted x0.01.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import optax

from mjx_form.rl import learner as learner_lib
from mjx_form.rl import normalizer
from mjx_form.rl.networks import Networks


CLONING_LOSSES = ("likelihood", "decoupled", "squared")
# run.py's default for BC and BCO. Offline on reacher_easy (180 expert episodes, 4,000 updates of
# 6,400 pairs, one seed; benchmarks/cloning_fit.py, NOTES sessions 70-71) the mean action's
# training error and the return over 32 episodes, at learning rate 1e-4 / 1e-3: squared 0.0034 ->
# 586 / 0.0015 -> 868, decoupled 0.0117 -> 213 / 0.0077 -> 172, likelihood 0.033 -> 73 / 0.046 -> 66.
DEFAULT_CLONING_LOSS = "squared"


def fit_loss(pi, actions: jax.Array, kind: str = "likelihood",
             scale_weight: float = 1.0, scale_pi=None) -> jax.Array:
  """Per pair loss [N] of a Gaussian `pi` (batch [N], mean and scale [N, A]) fitted to actions
  [N, A]: -log pi(a) ("likelihood"), or the decoupled fit (module docstring) with its scale
  term weighted by `scale_weight`; "squared" is the decoupled fit with the scale taken from
  `scale_pi` (the policy on held features; default `pi`)."""
  if kind == "likelihood":
    return -pi.log_prob(actions)
  if kind not in ("decoupled", "squared"):
    raise ValueError(f"unknown cloning loss {kind!r}; valid: {', '.join(CLONING_LOSSES)}")
  scale = pi.scale if kind == "decoupled" or scale_pi is None else scale_pi.scale
  held = pi._replace(mean=jax.lax.stop_gradient(pi.mean), scale=scale)
  return (0.5 * jnp.sum(jnp.square(pi.mean - actions), axis=-1)
          - scale_weight * held.log_prob(actions))


def loss(networks: Networks, policy_params, obs: jax.Array, actions: jax.Array,
         kind: str = "likelihood", scale_weight: float = 1.0) -> tuple[jax.Array, dict]:
  """The mean `fit_loss` over standardised observations [N, D] and actions [N, A], and the
  metrics: the mean log-likelihood, the mean squared error of the policy's mean action, its
  mean scale and entropy, and the share of its mean outside [-1, 1] (as MPO's)."""
  pi = networks.policy.apply(policy_params, obs)  # [N, A]
  scale_pi = (networks.policy.apply(policy_params, obs, hold_features=True)
              if kind == "squared" else None)
  log_prob = pi.log_prob(actions)  # [N]
  metrics = {"bc_log_prob": jnp.mean(log_prob),
             "bc_action_error": jnp.mean(jnp.square(pi.mean - actions)),
             "scale_mean": jnp.mean(pi.scale), "entropy": jnp.mean(pi.entropy()),
             "mean_out_of_bounds": jnp.mean(jnp.abs(pi.mean) > 1.0)}
  return jnp.mean(fit_loss(pi, actions, kind, scale_weight, scale_pi)), metrics


def update(networks: Networks, config: learner_lib.LearnerConfig,
           state: learner_lib.LearnerState, norm: normalizer.NormalizerState, obs: jax.Array,
           actions: jax.Array) -> tuple[learner_lib.LearnerState, dict]:
  """One optimiser step of the policy on raw observations [N, D] (standardised by `norm`, as
  the actors see them) and the actions [N, A] to clone; returns (state, metrics)."""
  x = normalizer.normalize(norm, obs)
  grad, metrics = jax.grad(lambda p: loss(networks, p, x, actions, config.cloning_loss),
                           has_aux=True)(state.policy)
  change, opt = learner_lib.policy_optimizer(config).update(grad, state.policy_opt, state.policy)
  state = state._replace(policy=optax.apply_updates(state.policy, change), policy_opt=opt,
                         updates=state.updates + 1)
  if state.average_policy is not None:
    state = state._replace(average_policy=learner_lib.averaged(
        state.average_policy, state.policy, config.policy_average_decay, state.updates))
  metrics["policy_grad_norm"] = jnp.sqrt(sum(jnp.sum(jnp.square(g))
                                             for g in jax.tree.leaves(grad)))
  return state, metrics
