"""Vision PPO: an asymmetric actor-critic on rsl-rl.

Actor: side + wrist RGB and proprioception -> ``VisualEncoder`` (an image backbone shared by
both cameras, then per camera a cross-attention pooling of the image tokens into
``queries_per_camera`` learned queries of ``token_dim``) -> features -> rsl-rl MLP head
(hidden 512) -> Gaussian actions (sigma0 0.05).  Critic: an rsl-rl MLP on the 42-d
privileged state.

Training, in two stages:
1. Behaviour cloning: a teacher (a trained state-policy run, or the task's scripted expert)
   drives the environments; the encoder and the head learn its actions (MSE).  With
   ``bc_dagger_waves`` (a state-policy teacher only), DAgger waves follow: the clone drives a
   growing share of the steps, the teacher labels every state, and the clone is fitted again to
   all the labels so far (the clone learns to recover from its own drift).
2. The encoder (backbone + pooling) is frozen; PPO fine-tunes the head and trains the critic.
   Because the encoder is frozen, the PPO adapter encodes the images once per step and
   rsl-rl's rollout storage holds features, not images.

Backbones: ``small_cnn`` (default): a small randomly initialised convolutional network with
coordinate channels; or ``timm:<model>`` (e.g. ``timm:vit_small_patch14_dinov2``) built by
timm without download and loaded from ``backbone_weights`` (a local ``.pt``/``.pth`` state
dict or ``.safetensors`` file).  timm is optional (not a WireCraft dependency).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from wirecraft.rl.common import EPISODE_FLAGS
from wirecraft.rl.config import VisionPPOConfig

CAMERAS = ("rgb_side", "rgb_wrist")
ENCODER_FILE = "encoder.pt"


# -- encoder -------------------------------------------------------------------------------------
class SmallConvBackbone(nn.Module):
    """(B, H, W, 3) uint8 -> (B, T, C) tokens: four stride-2 convolutions, then the token's
    normalised (x, y) position appended (attention pooling has no other sense of place)."""

    def __init__(self, width: int = 64) -> None:
        super().__init__()
        self.convs = nn.Sequential(
            nn.Conv2d(3, 32, 5, stride=2, padding=2),
            nn.ELU(),
            nn.Conv2d(32, width, 3, stride=2, padding=1),
            nn.ELU(),
            nn.Conv2d(width, width, 3, stride=2, padding=1),
            nn.ELU(),
            nn.Conv2d(width, width, 3, stride=2, padding=1),
            nn.ELU(),
        )
        self.out_dim = width + 2

    def forward(self, images: torch.Tensor) -> torch.Tensor:
        x = images.permute(0, 3, 1, 2).float() / 255.0
        features = self.convs((x - 0.5) / 0.25)
        b, _, h, w = features.shape
        ys = torch.linspace(-1.0, 1.0, h, device=features.device)
        xs = torch.linspace(-1.0, 1.0, w, device=features.device)
        grid = torch.stack(torch.meshgrid(xs, ys, indexing="xy"), dim=0).expand(b, 2, h, w)
        return torch.cat([features, grid], dim=1).flatten(2).transpose(1, 2)


class TimmBackbone(nn.Module):
    """A timm vision transformer's patch tokens (prefix tokens dropped), ImageNet-normalised
    input; weights from a local file only."""

    MEAN = (0.485, 0.456, 0.406)
    STD = (0.229, 0.224, 0.225)

    def __init__(self, model_name: str, weights: str | None, image_size: int) -> None:
        super().__init__()
        try:
            import timm
        except ImportError:
            raise ValueError(
                f"backbone 'timm:{model_name}' needs the timm package, which is not installed; "
                "use backbone='small_cnn' or install timm"
            ) from None
        try:
            self.model = timm.create_model(
                model_name, pretrained=False, num_classes=0, img_size=image_size
            )
        except Exception as err:  # timm raises several kinds for unknown names / sizes
            raise ValueError(
                f"timm cannot build {model_name!r} at {image_size} px: {err}"
            ) from None
        if weights:
            self.model.load_state_dict(load_weights(weights))
        self.out_dim = int(self.model.num_features)
        self.prefix_tokens = int(getattr(self.model, "num_prefix_tokens", 1))
        self.register_buffer("mean", torch.tensor(self.MEAN).view(1, 3, 1, 1))
        self.register_buffer("std", torch.tensor(self.STD).view(1, 3, 1, 1))

    def forward(self, images: torch.Tensor) -> torch.Tensor:
        x = images.permute(0, 3, 1, 2).float() / 255.0
        tokens = self.model.forward_features((x - self.mean) / self.std)
        return tokens[:, self.prefix_tokens :]


def load_weights(path: str) -> dict:
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"backbone weights: no such file {path}")
    if path.suffix == ".safetensors":
        from safetensors.torch import load_file

        return load_file(str(path))
    state = torch.load(path, map_location="cpu", weights_only=True)
    return state.get("state_dict", state) if isinstance(state, dict) else state


class AttentionPooling(nn.Module):
    """(B, T, C) tokens -> (B, queries * dim): learned queries attend over the tokens."""

    def __init__(self, in_dim: int, queries: int, dim: int, heads: int) -> None:
        super().__init__()
        self.queries = nn.Parameter(torch.randn(queries, dim) * 0.02)
        self.project = nn.Linear(in_dim, dim)
        self.norm = nn.LayerNorm(dim)
        self.attention = nn.MultiheadAttention(dim, heads, batch_first=True)

    def forward(self, tokens: torch.Tensor) -> torch.Tensor:
        keys = self.norm(self.project(tokens))
        queries = self.queries.expand(tokens.shape[0], -1, -1)
        pooled, _ = self.attention(queries, keys, keys, need_weights=False)
        return pooled.flatten(1)


class VisualEncoder(nn.Module):
    """Both cameras through one backbone, one pooling per camera, plus normalised
    proprioception: (B, cameras * queries * dim + proprio_dim) features."""

    def __init__(self, cfg: VisionPPOConfig, image_size: int, proprio_dim: int) -> None:
        super().__init__()
        if cfg.backbone == "small_cnn":
            if cfg.backbone_weights:
                raise ValueError("backbone_weights is for a timm backbone, not 'small_cnn'")
            self.backbone = SmallConvBackbone()
        else:
            self.backbone = TimmBackbone(cfg.backbone[5:], cfg.backbone_weights, image_size)
        self.pools = nn.ModuleDict(
            {
                camera: AttentionPooling(
                    self.backbone.out_dim,
                    cfg.queries_per_camera,
                    cfg.token_dim,
                    cfg.attention_heads,
                )
                for camera in CAMERAS
            }
        )
        self.image_size = image_size
        self.proprio_dim = proprio_dim
        self.register_buffer("proprio_mean", torch.zeros(proprio_dim))
        self.register_buffer("proprio_std", torch.ones(proprio_dim))
        self.out_dim = len(CAMERAS) * cfg.queries_per_camera * cfg.token_dim + proprio_dim

    def set_proprio_stats(self, proprio: torch.Tensor) -> None:
        self.proprio_mean.copy_(proprio.float().mean(0))
        self.proprio_std.copy_(proprio.float().std(0).clamp(min=1e-3))

    def forward(self, obs: dict[str, torch.Tensor]) -> torch.Tensor:
        batch = obs[CAMERAS[0]].shape[0]
        tokens = self.backbone(torch.cat([obs[c] for c in CAMERAS], dim=0))
        pooled = [self.pools[c](tokens[i * batch : (i + 1) * batch]) for i, c in enumerate(CAMERAS)]
        proprio = (obs["proprio"].float() - self.proprio_mean) / self.proprio_std
        return torch.cat([*pooled, proprio], dim=-1)

    def encode_numpy(self, obs: dict, chunk: int = 64) -> torch.Tensor:
        """Features of a batch of numpy observations (no gradient)."""
        with torch.no_grad():
            n = len(obs["proprio"])
            parts = []
            for s in range(0, n, chunk):
                part = {c: torch.as_tensor(np.asarray(obs[c][s : s + chunk])) for c in CAMERAS}
                part["proprio"] = torch.as_tensor(np.asarray(obs["proprio"][s : s + chunk]))
                parts.append(self(part))
            return torch.cat(parts)

    def freeze(self) -> VisualEncoder:
        for p in self.parameters():
            p.requires_grad_(False)
        return self.eval()


def check_image_obs(obs: dict, image_size: int) -> None:
    missing = [k for k in (*CAMERAS, "proprio") if k not in obs]
    if missing:
        raise ValueError(
            f"vision policy needs observations with {', '.join(missing)} (obs_mode 'rgb' or "
            "'state_rgb')"
        )
    shape = np.shape(obs[CAMERAS[0]])[-3:]
    if shape != (image_size, image_size, 3):
        raise ValueError(
            f"vision policy was trained on {image_size}x{image_size} images, got {shape}"
        )


# -- behaviour cloning ---------------------------------------------------------------------------
def _teacher_policy(venv, task: str, teacher: str | None, seed: int):
    """The teacher's ``act(obs)`` on ``venv``'s observations and its ``reset``: a state-policy
    run (memoryless) or, with ``teacher=None``, the task's scripted expert."""
    if teacher is None:
        from wirecraft.experts import expert_class

        expert = expert_class(task)(venv, seed=seed)
        return expert.act, expert.reset
    from wirecraft.rl import load_policy

    policy = load_policy(teacher, venv)
    return (lambda obs: policy.act(obs["state"])), policy.reset


def _observation_store() -> dict[str, list]:
    return {k: [] for k in (*CAMERAS, "proprio", "actions")}


def _keep(store: dict[str, list], obs: dict, labels: np.ndarray) -> None:
    for key in (*CAMERAS, "proprio"):
        store[key].append(np.asarray(obs[key]).copy())
    store["actions"].append(np.asarray(labels, dtype=np.float32))


def _as_tensors(store: dict[str, list], count: int | None = None) -> dict[str, torch.Tensor]:
    data = {k: torch.as_tensor(np.concatenate(v)[:count]) for k, v in store.items()}
    data["proprio"] = data["proprio"].float()
    data["actions"] = data["actions"].float()
    return data


def collect_teacher_data(
    task: str,
    env_kwargs: dict,
    teacher: str | None,
    transitions: int,
    *,
    num_envs: int,
    seed: int,
    threads: int,
    progress: bool,
) -> dict[str, torch.Tensor]:
    """Images, proprioception and the teacher's actions along the teacher's own rollouts."""
    from tqdm import tqdm

    import wirecraft

    venv = wirecraft.make_vec(task, num_envs, threads=threads, **env_kwargs)
    store = _observation_store()
    bar = tqdm(total=transitions, desc="teacher rollouts", unit="step", disable=not progress)
    count = 0
    try:
        teach, reset = _teacher_policy(venv, task, teacher, seed)
        obs, _ = venv.reset(seed=seed)
        reset()
        while count < transitions:
            actions = teach(obs)
            _keep(store, obs, actions)
            obs, *_ = venv.step(actions)
            count += num_envs
            bar.update(num_envs)
    finally:
        bar.close()
        venv.close()
    return _as_tensors(store, transitions)


def student_actions(encoder: VisualEncoder, actor, obs: dict) -> np.ndarray:
    """The (encoder, actor head) pair's deterministic actions on numpy observations."""
    from tensordict import TensorDict

    features = encoder.encode_numpy(obs)
    with torch.no_grad():
        td = TensorDict({"features": features}, batch_size=[len(features)])
        return np.clip(actor(td).numpy().astype(np.float64), -1.0, 1.0)


def dagger_wave(
    task: str,
    env_kwargs: dict,
    teacher: str,
    student,
    beta: float,
    *,
    num_envs: int,
    seed: int,
    threads: int,
    progress: bool,
) -> tuple[dict[str, torch.Tensor], dict[str, float]]:
    """One DAgger wave: one episode in each of ``num_envs`` environments; at every step the
    teacher (a state-policy run, whose action depends on the state alone) labels the state,
    and each environment executes the teacher's action with probability ``beta``, else
    ``student(obs)``'s.  Returns the labelled observations and, for each of the task's success
    flags (``success``, ``reach_success``, ``insert_success``: those its ``info`` has), the
    share of environments that raised it at some step of the wave, keyed ``success``,
    ``reach``, ``insert``."""
    from tqdm import tqdm

    import wirecraft

    venv = wirecraft.make_vec(task, num_envs, threads=threads, **env_kwargs)
    rng = np.random.default_rng(seed)
    store = _observation_store()
    raised: dict[str, np.ndarray] = {}
    try:
        teach, reset = _teacher_policy(venv, task, teacher, seed)
        obs, _ = venv.reset(seed=seed)
        reset()
        steps = int(venv.unwrapped.envs[0].max_steps)
        for _ in tqdm(range(steps), desc=f"DAgger wave (beta {beta:g})", disable=not progress):
            labels = teach(obs)
            actions = np.array(labels, dtype=np.float64)
            learner = rng.random(num_envs) >= beta
            if learner.any():
                actions[learner] = student(obs)[learner]
            _keep(store, obs, labels)
            obs, _, _, _, info = venv.step(actions)
            for flag in EPISODE_FLAGS:
                if flag in info:
                    seen = raised.setdefault(flag, np.zeros(num_envs, bool))
                    seen |= np.asarray(info[flag], bool)
    finally:
        venv.close()
    rates = {flag.removesuffix("_success"): float(seen.mean()) for flag, seen in raised.items()}
    return _as_tensors(store), rates


def concatenate(first: dict[str, torch.Tensor], second: dict[str, torch.Tensor]) -> dict:
    return {k: torch.cat([first[k], second[k]]) for k in first}


def behaviour_clone(
    encoder: VisualEncoder,
    actor,
    data: dict[str, torch.Tensor],
    cfg: VisionPPOConfig,
    *,
    progress: bool,
    log=None,
) -> list[float]:
    """Fit encoder and actor head to the teacher's actions (MSE on the mean action); returns
    the mean loss of each epoch."""
    from tensordict import TensorDict
    from tqdm import tqdm

    encoder.set_proprio_stats(data["proprio"])
    params = list(actor.parameters()) + list(encoder.pools.parameters())
    if cfg.bc_train_backbone:
        params += list(encoder.backbone.parameters())
    optimizer = torch.optim.Adam(params, lr=cfg.bc_learning_rate)
    n = len(data["actions"])
    generator = torch.Generator().manual_seed(cfg.seed)
    losses = []
    encoder.train()
    actor.train()
    for epoch in tqdm(range(cfg.bc_epochs), desc="behaviour cloning", disable=not progress):
        order = torch.randperm(n, generator=generator)
        total, batches = 0.0, 0
        for s in range(0, n, cfg.bc_batch_size):
            idx = order[s : s + cfg.bc_batch_size]
            features = encoder({k: data[k][idx] for k in (*CAMERAS, "proprio")})
            td = TensorDict({"features": features}, batch_size=[len(idx)])
            loss = F.mse_loss(actor(td), data["actions"][idx])
            optimizer.zero_grad()
            loss.backward()
            nn.utils.clip_grad_norm_(params, 1.0)
            optimizer.step()
            total += float(loss.item())
            batches += 1
        losses.append(total / max(batches, 1))
        if log is not None:
            log(epoch, losses[-1])
    return losses


def vision_observations(encoder: VisualEncoder):
    """Observation groups for the PPO adapter: frozen-encoder features for the actor, the
    privileged state for the critic."""

    def groups(obs) -> dict:
        return {"features": encoder.encode_numpy(obs), "state": obs["state"]}

    return groups


def save_encoder(encoder: VisualEncoder, cfg: VisionPPOConfig, path: Path) -> None:
    torch.save(
        {
            "state_dict": encoder.state_dict(),
            "image_size": encoder.image_size,
            "proprio_dim": encoder.proprio_dim,
        },
        path,
    )


def load_encoder(cfg: VisionPPOConfig, path: Path) -> VisualEncoder:
    saved = torch.load(path, map_location="cpu", weights_only=True)
    # the saved state holds the backbone: build it without reloading pretrained weights
    build_cfg = cfg.updated(backbone_weights=None)
    encoder = VisualEncoder(build_cfg, int(saved["image_size"]), int(saved["proprio_dim"]))
    encoder.load_state_dict(saved["state_dict"])
    return encoder.freeze()


class VisionPolicy:
    """A trained vision PPO actor: deterministic actions from numpy image observations."""

    def __init__(self, encoder: VisualEncoder, actor, control: str) -> None:
        self.encoder = encoder.freeze()
        self.actor = actor.eval()
        self.control = control

    def reset(self, env_ids=None) -> None:
        del env_ids

    def act(self, obs) -> np.ndarray:
        obs = dict(obs)
        if np.ndim(obs[CAMERAS[0]]) == 3:  # one environment: add the batch axis
            obs = {k: np.asarray(obs[k])[None] for k in (*CAMERAS, "proprio")}
        check_image_obs(obs, self.encoder.image_size)
        return student_actions(self.encoder, self.actor, obs)


def load_vision_policy(run: dict, run_dir: Path, checkpoint: Path) -> VisionPolicy:
    from wirecraft.rl.config import config_from_dict
    from wirecraft.rl.ppo import build_actor

    cfg = config_from_dict("vision-ppo", run["config"])
    encoder = load_encoder(cfg, run_dir / ENCODER_FILE)
    actor = build_actor(
        cfg, encoder.out_dim, int(run["action_dim"]), groups=("features",), normalization=False
    )
    saved = torch.load(checkpoint, map_location="cpu", weights_only=False)
    actor.load_state_dict(saved["actor_state_dict"])
    return VisionPolicy(encoder, actor, run["control"])
