"""The MPO learner step: Retrace critic loss, MPO policy loss, Adam, target networks.

One `update` consumes a batch of B unrolls of T steps (observations [B, T+1, D], raw) and
rewards [B, T] from a reward source. Q targets use the target critic and the target policy:
  v(x) = mean over `num_action_samples` actions a ~ pi_target(x) of Q_target(x, a)
  Retrace(lambda) with c_t = lambda min(1, pi_target(a_t|x_t) / mu(a_t|x_t)), mu = behaviour.
The MPO E-step reuses the same samples and target Q values at x_0 .. x_{T-1}. Policy, critic
and duals have their own Adam optimisers; targets are copied from the online networks every
`target_update_period` updates (at updates 0, P, 2P, ...).

With `policy_average_decay` d > 0 the state also keeps the policy's parameters averaged over
updates (`average_policy`, for evaluation only: acting and learning use the online policy):
after update n (n = 1, 2, ...) a <- d_n a + (1 - d_n) theta_n, d_n = min(d, (n - 1) / n), the
plain mean of all updates' parameters until n reaches 1 / (1 - d), an exponential average after.
"""

from __future__ import annotations

import dataclasses
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import optax

from mjx_form.rl import mpo, normalizer, retrace
from mjx_form.rl.networks import Networks


@dataclasses.dataclass(frozen=True)
class LearnerConfig:
  """The paper's settings (../shared/DESIGN.md) unless stated."""

  discount: float = 0.99
  retrace_lambda: float = 1.0
  num_action_samples: int = 20
  target_update_period: int = 200
  learning_rate: float = 1e-4
  dual_learning_rate: float = 1e-3
  max_grad_norm: float = 40.0  # Acme's MPO clips gradients at 40 (not stated in the paper)
  # The critic sees clip(a, -1, 1), the action the environment applies where its control range
  # is [-1, 1] (every task but quadruped's: its lift actuators go to 1.1, its extenders to 0.8,
  # `Task.action_bounds`), as Acme's control-suite MPO does (`ClipToSpec`); off: the paper's
  # critic sees tanh of the unclipped sample, so two actions the environment cannot tell apart
  # get different values.
  clip_critic_actions: bool = False
  # The target critic's Q of the sampled actions (20 per state: half of an update's time on a
  # GPU) computed in bfloat16 instead of float32 (`sampled_q`); off: the paper's precision.
  sampled_q_bfloat16: bool = False
  # With `sampled_q_bfloat16`, the critic's last layer (h -> Q) in float32 from the bfloat16
  # features: Q is no longer rounded to bfloat16, whose spacing (0.25 at Q in [32, 64), 0.5 in
  # [64, 128)) exceeds the spread of Q over a state's sampled actions once returns are high
  # (humanoid_stand at Q ~80: rounding error 3x that spread, NOTES session 60). Costs one
  # float32 matrix-vector product per sampled action. No effect without bfloat16.
  sampled_q_float32_head: bool = False
  # d of the policy's parameters averaged over updates (module docstring); 0: none kept (the
  # paper evaluates the online policy).
  policy_average_decay: float = 0.0
  # How BC and BCO fit the policy to actions (cloning.py): "likelihood" (the paper's) or
  # "decoupled" (the mean by squared error, the scale by likelihood). MPO ignores it.
  cloning_loss: str = "likelihood"
  mpo: mpo.MPOConfig = mpo.MPOConfig()


class LearnerState(NamedTuple):
  policy: Any  # flax params
  critic: Any
  target_policy: Any
  target_critic: Any
  duals: mpo.MPODuals
  policy_opt: Any
  critic_opt: Any
  dual_opt: Any
  updates: jax.Array  # int32 [], learner updates taken
  average_policy: Any = None  # the policy averaged over updates; None: not kept


def policy_optimizer(config: LearnerConfig):
  """The policy's (and the critic's) optimiser: Adam, gradients clipped by global norm."""
  return optax.chain(optax.clip_by_global_norm(config.max_grad_norm),
                     optax.adam(config.learning_rate))


def _optimizers(config: LearnerConfig):
  return policy_optimizer(config), policy_optimizer(config), optax.adam(config.dual_learning_rate)


def init(networks: Networks, config: LearnerConfig, key: jax.Array, observation_size: int,
         action_size: int) -> LearnerState:
  """Fresh parameters, targets equal to them, optimiser and dual states (and the average
  policy, equal to the policy, where `policy_average_decay` keeps one)."""
  policy_key, critic_key = jax.random.split(key)
  obs = jnp.zeros((1, observation_size))
  policy = networks.policy.init(policy_key, obs)
  critic = networks.critic.init(critic_key, obs, jnp.zeros((1, action_size)))
  duals = mpo.init_duals(config.mpo, action_size)
  policy_tx, critic_tx, dual_tx = _optimizers(config)
  return LearnerState(policy, critic, policy, critic, duals, policy_tx.init(policy),
                      critic_tx.init(critic), dual_tx.init(duals), jnp.zeros((), jnp.int32),
                      policy if keeps_average(config) else None)


def keeps_average(config: LearnerConfig) -> bool:
  """Whether the state keeps an average policy (a Python decision: the state's structure)."""
  return config.policy_average_decay > 0


def averaged(average, policy, decay, updates: jax.Array):
  """The average policy after update `updates` (n >= 1) made `policy` (module docstring)."""
  n = updates.astype(jnp.float32)
  d = jnp.minimum(decay, (n - 1.0) / n)
  return jax.tree.map(lambda a, p: d * a + (1.0 - d) * p, average, policy)


def _retrace_unroll() -> int | bool:
  """How the Retrace recursion is compiled; the values are the same either way.

  Unrolled on GPUs: as a 100-step loop it cost 0.5 of the 2.4 ms of an update on an H200
  (benchmarks/update_speed.py). A loop on the CPU: unrolled, the CI learning test took 183 s
  instead of 129 s.
  """
  return 1 if jax.default_backend() == "cpu" else True


def sampled_q(networks: Networks, config: LearnerConfig, critic_params, obs: jax.Array,
              actions: jax.Array) -> jax.Array:
  """Q of N actions per state, obs [B, T+1, D] and actions [N, B, T+1, A] -> [N, B, T+1]
  (float32); with `sampled_q_bfloat16` the critic's parameters and inputs are cast to bfloat16
  (LayerNorm's statistics stay float32) and Q is cast back, or with `sampled_q_float32_head`
  (a Python or a member's traced bool) only the features are: the last layer runs in float32
  on the float32 parameters."""
  if not config.sampled_q_bfloat16:
    return networks.critic.apply(critic_params, obs, actions)
  cast = lambda tree: jax.tree.map(lambda x: x.astype(jnp.bfloat16), tree)
  rounded = lambda: networks.critic.apply(cast(critic_params), cast(obs), cast(actions)).astype(
      jnp.float32)
  if config.sampled_q_float32_head is False:
    return rounded()
  h = networks.critic.apply(cast(critic_params), cast(obs), cast(actions),
                            features_only=True)  # [N, B, T+1, F] bfloat16
  head = critic_params["params"][networks.critic.head_name]
  exact = (jnp.matmul(h.astype(jnp.float32), head["kernel"], precision=jax.lax.Precision.HIGHEST)
           + head["bias"])[..., 0]
  if config.sampled_q_float32_head is True:
    return exact
  # (a member's traced flag: both; the compiler computes their shared features once)
  return jnp.where(config.sampled_q_float32_head, exact, rounded())


def losses(networks: Networks, config: LearnerConfig, online: tuple, state: LearnerState,
           obs: jax.Array, batch: dict, rewards: jax.Array, key: jax.Array):
  """Critic + MPO loss of one batch; `online` = (policy, critic, duals) being differentiated.

  obs: standardised observations [B, T+1, D]; batch: action [B, T, A],
  behaviour_log_prob [B, T], discount [B, T]; rewards [B, T].
  """
  policy_params, critic_params, duals = online
  actions = batch["action"]
  # The critic's view of an action (a Python or a member's traced bool: see grid.py).
  seen = lambda a: jnp.where(config.clip_critic_actions, jnp.clip(a, -1.0, 1.0), a)
  target_pi = networks.policy.apply(state.target_policy, obs)  # [B, T+1, A]
  sampled = target_pi.sample(key, (config.num_action_samples,))  # [N, B, T+1, A]
  sampled_seen = seen(sampled)
  q_sampled = sampled_q(networks, config, state.target_critic, obs, sampled_seen)  # [N, B, T+1]
  v = jnp.mean(q_sampled, axis=0)  # [B, T+1]

  obs_t = obs[:, :-1]
  q_taken_target = networks.critic.apply(state.target_critic, obs_t, seen(actions))  # [B, T]
  log_rhos = (jax.tree.map(lambda x: x[:, :-1], target_pi).log_prob(actions)
              - batch["behaviour_log_prob"])
  targets = jax.vmap(retrace.retrace_targets, in_axes=(0, 0, 0, 0, 0, None, None))(
      q_taken_target, v[:, 1:], rewards, config.discount * batch["discount"], log_rhos,
      config.retrace_lambda, _retrace_unroll())
  q_online = networks.critic.apply(critic_params, obs_t, seen(actions))  # [B, T]
  critic_loss = 0.5 * jnp.mean(jnp.square(q_online - targets))

  online_pi = networks.policy.apply(policy_params, obs_t)  # [B, T, A]
  flat = lambda x: x.reshape((-1,) + x.shape[2:])  # [B, T, ...] -> [S, ...]
  n = config.num_action_samples
  policy_loss, metrics = mpo.mpo_loss(
      duals, jax.tree.map(flat, online_pi), jax.tree.map(lambda x: flat(x[:, :-1]), target_pi),
      sampled[:, :, :-1].reshape((n, -1, actions.shape[-1])),
      q_sampled[:, :, :-1].reshape((n, -1)), config.mpo)
  metrics = dict(metrics, critic_loss=critic_loss, q_online=jnp.mean(q_online),
                 retrace_target=jnp.mean(targets), reward=jnp.mean(rewards),
                 importance_weight=jnp.mean(jnp.minimum(1.0, jnp.exp(log_rhos))),
                 sampled_all_beyond=all_beyond(sampled[:, :, :-1]),  # (MPO's states)
                 **sampled_q_diagnostics(networks, config, state.target_critic, obs,
                                         sampled_seen, q_sampled))
  return critic_loss + policy_loss, metrics


def all_beyond(sampled: jax.Array) -> jax.Array:
  """The share of (state, action dimension) pairs whose N sampled actions [N, ..., A] all lie
  beyond the same bound of [-1, 1]: where the critic sees them clipped
  (`clip_critic_actions`), every sample has the same value in that dimension, and the E-step's
  weights cannot pull the policy's mean back from beyond the bound."""
  return jnp.mean(jnp.all(sampled > 1.0, axis=0) | jnp.all(sampled < -1.0, axis=0))


def sampled_q_diagnostics(networks: Networks, config: LearnerConfig, critic_params,
                          obs: jax.Array, actions: jax.Array, q_sampled: jax.Array) -> dict:
  """What the E-step's weights exp(Q / temperature) have to go on: `sampled_q_spread`, the sd
  of Q over a state's sampled actions (mean over states), and with `sampled_q_bfloat16`,
  `sampled_q_bf16_error`, the mean |Q| error of bfloat16's rounding, against float32 on the
  batch's first unroll (actions [N, B, T+1, A], q_sampled [N, B, T+1] as `sampled_q` gave),
  and `sampled_q_bf16_centred_error`, the rms of that error less its mean over each state's
  actions: the part the weights see (with `sampled_q_float32_head`, what the bfloat16
  features leave). Where it nears the spread or the temperature, the weights follow the
  rounding."""
  out = {"sampled_q_spread": jnp.mean(jnp.std(q_sampled, axis=0))}
  if config.sampled_q_bfloat16:
    exact = networks.critic.apply(critic_params, obs[:1], actions[:, :1])  # [N, 1, T+1]
    error = q_sampled[:, :1] - exact
    out["sampled_q_bf16_error"] = jnp.mean(jnp.abs(error))
    # what reaches the weights: the error less its mean over the state's actions (rms)
    out["sampled_q_bf16_centred_error"] = jnp.sqrt(jnp.mean(jnp.square(
        error - jnp.mean(error, axis=0))))
  return out


def update(networks: Networks, config: LearnerConfig, state: LearnerState,
           norm: normalizer.NormalizerState, batch: dict, rewards: jax.Array,
           key: jax.Array) -> tuple[LearnerState, dict]:
  """One learner update on a batch of unrolls (see `losses`); returns (state, metrics)."""
  # Targets follow the online networks every `target_update_period` updates.
  copy = state.updates % config.target_update_period == 0
  follow = lambda online, target: jax.tree.map(lambda o, t: jnp.where(copy, o, t), online, target)
  state = state._replace(target_policy=follow(state.policy, state.target_policy),
                         target_critic=follow(state.critic, state.target_critic))

  obs = normalizer.normalize(norm, batch["observation"])
  online = (state.policy, state.critic, state.duals)
  grads, metrics = jax.grad(lambda o: losses(networks, config, o, state, obs, batch, rewards,
                                             key), has_aux=True)(online)
  policy_tx, critic_tx, dual_tx = _optimizers(config)
  steps = {}
  for name, params, grad, opt, tx in (
      ("policy", state.policy, grads[0], state.policy_opt, policy_tx),
      ("critic", state.critic, grads[1], state.critic_opt, critic_tx),
      ("duals", state.duals, grads[2], state.dual_opt, dual_tx)):
    change, opt = tx.update(grad, opt, params)
    steps[name] = (optax.apply_updates(params, change), opt)
    metrics[f"{name}_grad_norm"] = jnp.sqrt(sum(jnp.sum(jnp.square(g))
                                                for g in jax.tree.leaves(grad)))
  state = state._replace(policy=steps["policy"][0], policy_opt=steps["policy"][1],
                         critic=steps["critic"][0], critic_opt=steps["critic"][1],
                         duals=mpo.clip_duals(steps["duals"][0]), dual_opt=steps["duals"][1],
                         updates=state.updates + 1)
  if state.average_policy is not None:
    state = state._replace(average_policy=averaged(state.average_policy, state.policy,
                                                   config.policy_average_decay, state.updates))
  return state, metrics
