"""Training configurations of the RL baselines, with the reference defaults (SPEC section 8).

Every field is checked at construction: a bad value raises a ``ValueError`` naming the field.
``replace(cfg, **overrides)`` (or ``cfg.updated(...)``) gives a checked copy;
``config_from_dict`` rebuilds one from the JSON of a run directory.

Step counts: "env steps" are transitions summed over environments (one vector step of N
environments is N env steps), as in the reference's step budgets.
"""

from __future__ import annotations

import dataclasses
import json
import math
import typing
from typing import Any, ClassVar

# Isaac Lab's reward manager multiplies every weighted term by the control period; the
# reference weights (reach 15 ... seated 1000) assume it.  Our environment returns the plain
# weighted sum per step, so PPO scales it by the control period (1/60 s) to match.
CONTROL_PERIOD = 1.0 / 60.0
# The SAC actor's clip of its log std: MAX_LOG_STD is the widest SACfDConfig.max_log_std allows.
MIN_LOG_STD, MAX_LOG_STD = -5.0, 2.0


def _positive(owner: str, name: str, value: float) -> None:
    if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
        raise ValueError(f"{owner}: {name} must be a finite number > 0, got {value!r}")


def _non_negative(owner: str, name: str, value: float) -> None:
    if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0):
        raise ValueError(f"{owner}: {name} must be a finite number >= 0, got {value!r}")


def _int_at_least(owner: str, name: str, value: int, low: int) -> None:
    if isinstance(value, bool) or not isinstance(value, int) or value < low:
        raise ValueError(f"{owner}: {name} must be an integer >= {low}, got {value!r}")


def _fraction(owner: str, name: str, value: float, *, closed: bool = True) -> None:
    ok = isinstance(value, (int, float)) and (0 <= value <= 1 if closed else 0 < value < 1)
    if not ok:
        bounds = "[0, 1]" if closed else "(0, 1)"
        raise ValueError(f"{owner}: {name} must be in {bounds}, got {value!r}")


def _layers(owner: str, name: str, value) -> tuple[int, ...]:
    layers = tuple(value)
    if not layers or any(isinstance(n, bool) or not isinstance(n, int) or n < 1 for n in layers):
        raise ValueError(
            f"{owner}: {name} must be a non-empty list of integers >= 1, got {value!r}"
        )
    return layers


ACTIVATIONS = ("elu", "relu", "tanh", "selu", "gelu")


@dataclasses.dataclass
class PPOConfig:
    """State PPO (rsl-rl): MLP actor and critic on the 42-d privileged state."""

    algorithm: ClassVar[str] = "ppo"

    num_envs: int = 64
    num_steps_per_env: int = 128
    max_iterations: int = 1000
    actor_hidden_dims: tuple[int, ...] = (256, 128, 64)
    critic_hidden_dims: tuple[int, ...] = (256, 128, 64)
    activation: str = "elu"
    init_std: float = 1.0
    obs_normalization: bool = True
    clip_param: float = 0.2
    entropy_coef: float = 0.01
    value_loss_coef: float = 1.0
    gamma: float = 0.99
    lam: float = 0.95
    learning_rate: float = 5e-4
    schedule: str = "adaptive"
    desired_kl: float = 0.01
    num_mini_batches: int = 8
    num_learning_epochs: int = 5
    max_grad_norm: float = 1.0
    reward_scale: float = CONTROL_PERIOD
    save_interval: int = 50  # iterations between checkpoints
    seed: int = 0
    threads: int = 0  # physics threads of the vector env (0: all CPUs)
    # Where the physics steps: "cpu" (MuJoCo's batch engine on threads) or "warp" (MuJoCo Warp
    # on warp_device, e.g. "cuda:0"; "" for Warp's preferred device).  The networks train on
    # the CPU either way.
    backend: str = "cpu"
    warp_device: str = ""
    # Not in the reference: the fraction of training episodes that start part-way through a
    # successful scripted-expert episode (rl/expert_starts.py), from states recorded every
    # expert_start_stride control steps of expert_start_episodes episodes.  0: fresh resets only.
    expert_starts: float = 0.0
    expert_start_episodes: int = 64
    expert_start_stride: int = 10
    # Not in the reference: before the first iteration, fit the actor to bc_init_transitions
    # scripted-expert transitions and the critic to their returns (ppo.behaviour_clone_init),
    # bc_init_epochs passes.  0: PPO starts from random weights.
    bc_init_transitions: int = 0
    bc_init_epochs: int = 10
    # Not in the reference: the actor's inputs (rl/features.py): "state", the 42-d state as the
    # critic sees it, or "relative", the state plus goal-relative vectors computed from it.
    actor_inputs: str = "state"
    # Not in the reference: before the first iteration, DAgger (rl/dagger.py) from the reactive
    # insertion expert: dagger_init_iterations waves of every environment, each labelled by the
    # expert and followed by dagger_init_epochs passes of the actor over all labels; then the
    # critic is fitted to the waves' returns.  0: off.
    dagger_init_iterations: int = 0
    dagger_init_epochs: int = 15
    # Not in the reference: during PPO, after each update, the reactive insertion expert labels
    # the rollout and the actor takes one regression pass toward the labels (its own Adam at
    # dagger_aux_lr * dagger_aux_decay ** iteration; rl/dagger.py auxiliary_dagger).  0: off.
    dagger_aux_lr: float = 0.0
    dagger_aux_decay: float = 1.0

    def __post_init__(self) -> None:
        owner = type(self).__name__
        from wirecraft import BACKENDS

        if self.backend not in BACKENDS:
            valid = " or ".join(repr(b) for b in BACKENDS)
            raise ValueError(f"{owner}: backend must be {valid}, got {self.backend!r}")
        if self.warp_device and self.backend != "warp":
            raise ValueError(f"{owner}: warp_device is for backend='warp' only")
        if self.actor_inputs not in ("state", "relative"):
            raise ValueError(
                f"{owner}: actor_inputs must be 'state' or 'relative', got {self.actor_inputs!r}"
            )
        _int_at_least(owner, "dagger_init_iterations", self.dagger_init_iterations, 0)
        _int_at_least(owner, "dagger_init_epochs", self.dagger_init_epochs, 1)
        _non_negative(owner, "dagger_aux_lr", self.dagger_aux_lr)
        _positive(owner, "dagger_aux_decay", self.dagger_aux_decay)  # with the next: (0, 1]
        _fraction(owner, "dagger_aux_decay", self.dagger_aux_decay)
        if self.dagger_init_iterations and self.bc_init_transitions:
            raise ValueError(f"{owner}: choose dagger_init_iterations or bc_init_transitions")
        _int_at_least(owner, "bc_init_transitions", self.bc_init_transitions, 0)
        _int_at_least(owner, "bc_init_epochs", self.bc_init_epochs, 1)
        _fraction(owner, "expert_starts", self.expert_starts)
        _int_at_least(owner, "expert_start_episodes", self.expert_start_episodes, 1)
        _int_at_least(owner, "expert_start_stride", self.expert_start_stride, 1)
        for name in ("num_envs", "num_steps_per_env", "max_iterations", "num_mini_batches"):
            _int_at_least(owner, name, getattr(self, name), 1)
        _int_at_least(owner, "num_learning_epochs", self.num_learning_epochs, 1)
        _int_at_least(owner, "save_interval", self.save_interval, 1)
        _int_at_least(owner, "seed", self.seed, 0)
        _int_at_least(owner, "threads", self.threads, 0)
        self.actor_hidden_dims = _layers(owner, "actor_hidden_dims", self.actor_hidden_dims)
        self.critic_hidden_dims = _layers(owner, "critic_hidden_dims", self.critic_hidden_dims)
        if self.activation not in ACTIVATIONS:
            raise ValueError(
                f"{owner}: activation must be one of {', '.join(ACTIVATIONS)}, "
                f"got {self.activation!r}"
            )
        if self.schedule not in ("adaptive", "fixed"):
            raise ValueError(
                f"{owner}: schedule must be 'adaptive' or 'fixed', got {self.schedule!r}"
            )
        for name in ("init_std", "learning_rate", "desired_kl", "max_grad_norm", "reward_scale"):
            _positive(owner, name, getattr(self, name))
        for name in ("clip_param", "gamma", "lam"):
            _fraction(owner, name, getattr(self, name), closed=False)
        _non_negative(owner, "entropy_coef", self.entropy_coef)
        _non_negative(owner, "value_loss_coef", self.value_loss_coef)
        batch = self.num_envs * self.num_steps_per_env
        if batch < self.num_mini_batches:
            raise ValueError(
                f"{owner}: num_envs x num_steps_per_env ({batch}) must be >= num_mini_batches "
                f"({self.num_mini_batches})"
            )

    @property
    def steps_per_iteration(self) -> int:
        return self.num_envs * self.num_steps_per_env

    def updated(self, **overrides):
        return replace(self, **overrides)


@dataclasses.dataclass
class VisionPPOConfig(PPOConfig):
    """Vision PPO: asymmetric actor-critic.  The actor sees side + wrist RGB and proprioception
    through an image encoder with cross-attention pooling; the critic sees the privileged state.
    The encoder (backbone + pooling) is behaviour-cloned from a teacher, then frozen; PPO
    fine-tunes the actor head."""

    algorithm: ClassVar[str] = "vision-ppo"

    num_envs: int = 64
    max_iterations: int = 600
    actor_hidden_dims: tuple[int, ...] = (512,)
    init_std: float = 0.05
    clip_param: float = 0.1
    desired_kl: float = 0.005
    entropy_coef: float = 0.0
    value_loss_coef: float = 0.3
    learning_rate: float = 1e-4
    # -- encoder
    backbone: str = "small_cnn"  # or "timm:<model name>", e.g. timm:vit_small_patch14_dinov2
    backbone_weights: str | None = None  # local file of pretrained backbone weights
    queries_per_camera: int = 8
    token_dim: int = 64
    attention_heads: int = 4
    # -- behaviour cloning of the encoder
    teacher: str | None = None  # a state-policy run directory; None: the scripted expert
    bc_transitions: int = 4096
    bc_epochs: int = 10
    bc_batch_size: int = 64
    bc_learning_rate: float = 3e-4
    bc_train_backbone: bool = True
    # DAgger after the teacher's own rollouts: waves in which the clone drives (teacher needed)
    bc_dagger_waves: int = 0
    bc_dagger_envs: int = 16  # environments per wave, one episode each

    def __post_init__(self) -> None:
        super().__post_init__()
        owner = type(self).__name__
        for name in (
            "expert_starts",
            "bc_init_transitions",
            "dagger_init_iterations",
            "dagger_aux_lr",
        ):
            if getattr(self, name):  # state PPO's; ours clones itself
                raise ValueError(f"{owner}: {name} is for state PPO; it must be 0 here")
        if self.actor_inputs != "state":
            raise ValueError(f"{owner}: actor_inputs is for state PPO; it must be 'state' here")
        if self.backbone != "small_cnn" and not self.backbone.startswith("timm:"):
            raise ValueError(
                f"{owner}: backbone must be 'small_cnn' or 'timm:<model name>', "
                f"got {self.backbone!r}"
            )
        for name in ("queries_per_camera", "token_dim", "attention_heads", "bc_transitions"):
            _int_at_least(owner, name, getattr(self, name), 1)
        _int_at_least(owner, "bc_epochs", self.bc_epochs, 0)
        _int_at_least(owner, "bc_dagger_waves", self.bc_dagger_waves, 0)
        _int_at_least(owner, "bc_dagger_envs", self.bc_dagger_envs, 1)
        if self.bc_dagger_waves and self.teacher is None:
            raise ValueError(
                f"{owner}: bc_dagger_waves needs a teacher that labels any state: set teacher "
                "to a state-policy run directory (the scripted expert's action depends on its "
                "own history, so it cannot label the clone's states)"
            )
        _int_at_least(owner, "bc_batch_size", self.bc_batch_size, 1)
        _positive(owner, "bc_learning_rate", self.bc_learning_rate)
        if self.token_dim % self.attention_heads:
            raise ValueError(
                f"{owner}: token_dim ({self.token_dim}) must be divisible by attention_heads "
                f"({self.attention_heads})"
            )


@dataclasses.dataclass
class SACfDConfig:
    """SAC from demonstrations (skrl SAC + a scripted-expert replay buffer and a BC term)."""

    algorithm: ClassVar[str] = "sacfd"

    num_envs: int = 16
    total_steps: int = 1_000_000  # env steps
    hidden_dims: tuple[int, ...] = (256, 256)
    activation: str = "elu"
    gamma: float = 0.99
    tau: float = 0.005
    learning_rate: float = 3e-4
    batch_size: int = 256
    updates_per_env_step: float = 1.0  # gradient steps per env step (N per vector step)
    replay_per_env: int = 8000
    warmup_steps: int = 5000  # env steps before the first update
    learn_entropy: bool = True
    target_entropy: float = -7.0
    initial_alpha: float = 0.1
    # The reference's 0.01 applied to Isaac Lab's rewards, which its reward manager weights by
    # the step period (PPOConfig.reward_scale): the same scale here is 0.01 of a period.
    reward_scale: float = 0.01 * CONTROL_PERIOD
    obs_normalization: bool = True  # skrl's RunningStandardScaler
    demo_transitions: int = 150_000
    demo_success_only: bool = True  # keep only the expert's successful episodes
    demo_ratio: float = 0.5
    bc_weight_start: float = 2.5
    bc_weight_end: float = 0.5
    bc_anneal_start: int = 80_000  # env steps
    bc_anneal_end: int = 250_000
    # Not in the reference (docs/baselines.md, "SACfD"): the expert whose episodes fill the
    # demonstration buffer, the task's "scripted" one or its memoryless "reactive" one.
    demo_expert: str = "scripted"
    # Not in the reference: what actor and critics read (rl/features.py), "state" or
    # "relative" (the state plus goal-relative vectors computed from it).
    inputs: str = "state"
    # Not in the reference: the behaviour-cloning term's pairs, "demos" (the demonstration
    # buffer's) or "replay" (states from the agent's own replay buffer, labelled by the task's
    # reactive expert: DAgger).
    bc_states: str = "demos"
    # Not in the reference: Adam steps fitting the actor's mean to the demonstrations (and its
    # spread to the fit's residual) before the first env step.  0: SAC starts from random
    # weights.
    bc_init_steps: int = 0
    # Not in the reference: a DAgger warm start of the actor before the first SAC step
    # (rl/dagger.py's waves on dagger_init_envs environments, each fitted dagger_init_epochs
    # passes as bc_init_steps fits).  0: off.
    dagger_init_iterations: int = 0
    dagger_init_epochs: int = 15
    dagger_init_envs: int = 64
    # Not in the reference: for this many env steps after the first update (of each start or
    # resumption), SAC updates the critics and the temperature but not the actor, which the BC
    # term alone moves, so that the actor's first SAC steps follow critics that have learnt
    # its behaviour's values rather than their random initial ones.  0: off.
    critic_warmup_steps: int = 0
    # Not in the reference: the actor's Adam learning rate (its SAC and BC steps); 0: the
    # critics' learning_rate.
    actor_learning_rate: float = 0.0
    # The actor's log std is clipped to [-5, max_log_std]; lowering it bounds how far SAC's
    # samples stray from the mean.
    max_log_std: float = MAX_LOG_STD
    checkpoint_every_steps: int = 50_000
    log_every_steps: int = 10_000
    seed: int = 0
    threads: int = 0

    def __post_init__(self) -> None:
        owner = type(self).__name__
        from wirecraft.experts import DEMONSTRATORS
        from wirecraft.rl.features import ACTOR_INPUTS

        for name, value, valid in (
            ("demo_expert", self.demo_expert, DEMONSTRATORS),
            ("inputs", self.inputs, ACTOR_INPUTS),
            ("bc_states", self.bc_states, ("demos", "replay")),
        ):
            if value not in valid:
                raise ValueError(
                    f"{owner}: {name} must be one of {', '.join(valid)}, got {value!r}"
                )
        _int_at_least(owner, "bc_init_steps", self.bc_init_steps, 0)
        _int_at_least(owner, "dagger_init_iterations", self.dagger_init_iterations, 0)
        _int_at_least(owner, "dagger_init_epochs", self.dagger_init_epochs, 1)
        _int_at_least(owner, "dagger_init_envs", self.dagger_init_envs, 1)
        _int_at_least(owner, "critic_warmup_steps", self.critic_warmup_steps, 0)
        _non_negative(owner, "actor_learning_rate", self.actor_learning_rate)
        if not MIN_LOG_STD < self.max_log_std <= MAX_LOG_STD:
            raise ValueError(
                f"{owner}: max_log_std must be in ({MIN_LOG_STD}, {MAX_LOG_STD}], "
                f"got {self.max_log_std!r}"
            )
        for name in ("num_envs", "total_steps", "batch_size", "replay_per_env"):
            _int_at_least(owner, name, getattr(self, name), 1)
        for name in ("warmup_steps", "bc_anneal_start", "seed", "threads"):
            _int_at_least(owner, name, getattr(self, name), 0)
        for name in ("demo_transitions", "checkpoint_every_steps", "log_every_steps"):
            _int_at_least(owner, name, getattr(self, name), 1)
        self.hidden_dims = _layers(owner, "hidden_dims", self.hidden_dims)
        if self.activation not in ACTIVATIONS:
            raise ValueError(
                f"{owner}: activation must be one of {', '.join(ACTIVATIONS)}, "
                f"got {self.activation!r}"
            )
        for name in ("learning_rate", "initial_alpha", "reward_scale", "updates_per_env_step"):
            _positive(owner, name, getattr(self, name))
        _fraction(owner, "gamma", self.gamma, closed=False)
        _fraction(owner, "tau", self.tau)
        _fraction(owner, "demo_ratio", self.demo_ratio)
        _non_negative(owner, "bc_weight_start", self.bc_weight_start)
        _non_negative(owner, "bc_weight_end", self.bc_weight_end)
        if not math.isfinite(self.target_entropy):
            raise ValueError(f"{owner}: target_entropy must be finite, got {self.target_entropy!r}")
        if self.bc_anneal_end < self.bc_anneal_start:
            raise ValueError(
                f"{owner}: bc_anneal_end ({self.bc_anneal_end}) must be >= bc_anneal_start "
                f"({self.bc_anneal_start})"
            )

    def bc_weight(self, env_steps: int) -> float:
        """The BC loss weight after ``env_steps``: constant, then linear, then constant."""
        if env_steps <= self.bc_anneal_start:
            return self.bc_weight_start
        if env_steps >= self.bc_anneal_end:
            return self.bc_weight_end
        frac = (env_steps - self.bc_anneal_start) / (self.bc_anneal_end - self.bc_anneal_start)
        return self.bc_weight_start + frac * (self.bc_weight_end - self.bc_weight_start)

    @property
    def gradient_steps_per_vector_step(self) -> int:
        return max(1, round(self.updates_per_env_step * self.num_envs))

    def updated(self, **overrides):
        return replace(self, **overrides)


CONFIGS: dict[str, type] = {cls.algorithm: cls for cls in (PPOConfig, SACfDConfig, VisionPPOConfig)}


def replace(cfg, **overrides):
    """A checked copy of ``cfg`` with ``overrides``; unknown names are a ``ValueError``."""
    names = {f.name for f in dataclasses.fields(cfg)}
    unknown = sorted(set(overrides) - names)
    if unknown:
        raise ValueError(
            f"{type(cfg).__name__}: unknown setting(s) {', '.join(unknown)}; valid: "
            f"{', '.join(sorted(names))}"
        )
    return dataclasses.replace(cfg, **overrides)


def config_class(algorithm: str) -> type:
    if algorithm not in CONFIGS:
        raise ValueError(f"unknown algorithm {algorithm!r}; valid: {', '.join(CONFIGS)}")
    return CONFIGS[algorithm]


def config_to_dict(cfg) -> dict[str, Any]:
    return {k: list(v) if isinstance(v, tuple) else v for k, v in dataclasses.asdict(cfg).items()}


def config_from_dict(algorithm: str, values: dict[str, Any]):
    cls = config_class(algorithm)
    known = {f.name: f for f in dataclasses.fields(cls)}
    kwargs = {k: tuple(v) if isinstance(v, list) else v for k, v in values.items() if k in known}
    return cls(**kwargs)


def _declared_example(cls, name: str):
    """A value of the one type other than None that a dataclass field is declared with
    (``float | None`` gives 0.0), or None if that is not a plain bool, int, float or str."""
    hint = typing.get_type_hints(cls)[name]
    options = [t for t in (typing.get_args(hint) or (hint,)) if t is not type(None)]
    return options[0]() if len(options) == 1 and options[0] in (bool, int, float, str) else None


def parse_override(text: str, cfg) -> tuple[str, Any]:
    """``NAME=VALUE`` to a typed (name, value) for ``cfg``'s field ``NAME`` (any config
    dataclass; lists: comma-separated, of the current tuple's element type (str, float or
    int); booleans: true/false; tables (dicts): a JSON object; none: None; a field now None
    reads as its declared type)."""
    if "=" not in text:
        raise ValueError(f"--set expects NAME=VALUE, got {text!r}")
    name, raw = (s.strip() for s in text.split("=", 1))
    fields = {f.name: f for f in dataclasses.fields(cfg)}
    if name not in fields:
        raise ValueError(
            f"--set: unknown setting {name!r} for {type(cfg).__name__}; valid: "
            f"{', '.join(sorted(fields))}"
        )
    current = getattr(cfg, name)
    if current is None:
        current = _declared_example(type(cfg), name)
    try:
        if raw.lower() == "none":
            return name, None
        if isinstance(current, bool):
            if raw.lower() not in ("true", "false", "1", "0"):
                raise ValueError
            return name, raw.lower() in ("true", "1")
        if isinstance(current, dict):
            value = json.loads(raw)
            if not isinstance(value, dict):
                raise ValueError
            return name, value
        if isinstance(current, tuple):
            if any(isinstance(v, str) for v in current):
                element = str
            else:
                element = float if any(isinstance(v, float) for v in current) else int
            return name, tuple(element(v.strip()) for v in raw.split(",") if v.strip())
        if isinstance(current, int):
            return name, int(float(raw)) if "e" in raw.lower() else int(raw)
        if isinstance(current, float):
            return name, float(raw)
    except ValueError:
        raise ValueError(f"--set {name}: cannot read {raw!r} as {type(current).__name__}") from None
    return name, raw
