"""``wirecraft train act|diffusion``: LeRobot's own training (``lerobot-train``) on a dataset
written by ``wirecraft collect``, with the reference hyperparameters and matching environments.

Nothing here trains: the wrapper reads the dataset (``meta/info.json``: frame rate, features,
image size; ``meta/wirecraft_collect.json``: task, robot and task options), builds the
``lerobot-train`` command line (policy inputs = ``observation.state`` and both cameras; the
in-training evaluation environment ``--env.type=wirecraft_<family>`` with the dataset's image
size, frame rate, robot, wire and task options; no pretrained weights unless a local file is
given) and runs it in a child process (``python -m lerobot.scripts.lerobot_train``), whose log
is the progress.  ``--resume`` hands LeRobot its own resume (``--config_path`` of the last
checkpoint, ``--resume=true``).  The run folder gets ``wirecraft_il.json``: the commands, the
dataset and its collection record, and WireCraft's provenance.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from wirecraft.datasets.collect import SETTINGS_FILE as COLLECT_FILE
from wirecraft.datasets.writer import INFO_FILE

RUN_FILE = "wirecraft_il.json"
TRAINABLE = ("act", "diffusion")
# Accepted, but only as fine-tuning of a local checkpoint (--pretrained, lerobot-train's
# --policy.path), whose backbones must be on this machine (check_backbones).  SmolVLA can be
# built from scratch with random weights on a local backbone folder (tests/test_il_vla.py);
# pi0.5 cannot be made small: LeRobot 0.6 fixes its widths (gemma_300m at least, ~1.9 B
# parameters) and its pre-processor names the hub tokenizer google/paligemma-3b-pt-224.
FINE_TUNE_ONLY = ("smolvla", "pi05")
ALGORITHMS = TRAINABLE + FINE_TUNE_ONLY
STATE_KEY = "observation.state"
CAMERA_KEYS = ("observation.images.cam_side", "observation.images.cam_wrist")
LAST_CHECKPOINT = Path("checkpoints") / "last"
TRAIN_CONFIG = "train_config.json"

# Reference hyperparameters (SPEC section 8); the rest is LeRobot's policy defaults (ACT: a
# ResNet-18 backbone, 4 encoder / 1 decoder layers of width 512, VAE; Diffusion: a U-Net of
# (512, 1024, 2048), DDPM with 100 steps, ResNet-18; group norm in it when trained from scratch,
# as Diffusion Policy does).  The SPEC gives no batch
# size for Diffusion Policy: LeRobot's default (8) stays.
REFERENCE = {
    "act": {
        "steps": 100_000,
        "batch_size": 64,
        "policy": {"chunk_size": 100, "n_action_steps": 50, "optimizer_lr": 1e-5},
    },
    "diffusion": {
        "steps": 200_000,
        "batch_size": None,
        "policy": {
            "horizon": 16,
            "n_obs_steps": 2,
            "n_action_steps": 8,
            "drop_n_last_frames": 7,  # horizon - n_action_steps - n_obs_steps + 1
            "optimizer_lr": 1e-4,
        },
    },
}
# ``--preset cpu``: a starting point for training on a CPU, not a measured recipe.
PRESETS = {
    "cpu": {
        "act": {
            "steps": 20_000,
            "batch_size": 8,
            "policy": {
                "dim_model": 256,
                "n_heads": 4,
                "dim_feedforward": 1024,
                "n_encoder_layers": 1,
                "n_decoder_layers": 1,
                "chunk_size": 20,
                "n_action_steps": 10,
            },
        },
        "diffusion": {
            "steps": 20_000,
            "batch_size": 8,
            "policy": {"down_dims": "[64,128,256]", "diffusion_step_embed_dim": 64},
        },
    }
}
# Policy options the wrapper sets itself (other flags name them).
RESERVED_POLICY_KEYS = {
    "type": "the algorithm (first argument)",
    "input_features": "the wrapper (observation.state and both cameras)",
    "output_features": "the dataset",
    "device": "--device",
    "pretrained_path": "--pretrained",
    "path": "--pretrained",
    "push_to_hub": "the wrapper (never pushes)",
}
# lerobot-train options the wrapper sets itself.
RESERVED_TRAIN_KEYS = {
    "dataset.root": "--dataset",
    "dataset.repo_id": "--dataset",
    "output_dir": "--out",
    "resume": "--resume",
    "config_path": "--resume",
    "steps": "--steps",
    "batch_size": "--batch-size",
    "env.type": "the dataset's task",
    "policy": "--policy-arg",
}
# ImageNet ResNet-18 of torchvision: the file name LeRobot's backbones load (hash-checked).
RESNET18_FILE = "resnet18-f37072fd.pth"


def usage(flag: str, message: str) -> ValueError:
    return ValueError(f"{flag}: {message}")


# -- the dataset --------------------------------------------------------------------------------
def read_dataset(path: str | Path) -> tuple[dict, dict]:
    """(meta/info.json, meta/wirecraft_collect.json) of a ``wirecraft collect`` dataset."""
    root = Path(path)
    if not root.is_dir():
        raise usage("--dataset", f"{path} is not a folder (a dataset written by wirecraft collect)")
    for name in (INFO_FILE, COLLECT_FILE):
        if not (root / name).is_file():
            raise usage(
                "--dataset", f"{path} is not a dataset written by wirecraft collect (no {name})"
            )
    try:
        info = json.loads((root / INFO_FILE).read_text())
        collect = json.loads((root / COLLECT_FILE).read_text())
    except json.JSONDecodeError as err:
        raise usage("--dataset", f"{path}: unreadable metadata ({err})") from None
    features = info.get("features", {})
    missing = [k for k in (STATE_KEY, *CAMERA_KEYS, "action") if k not in features]
    if missing or not info.get("total_episodes"):
        what = f"no feature {', '.join(missing)}" if missing else "no episodes"
        raise usage("--dataset", f"{path} cannot be trained on: {what}")
    return info, collect


def input_features(info: dict) -> dict:
    """The policy's inputs: the joint state and both cameras (images channels first)."""
    features = info["features"]
    inputs = {STATE_KEY: {"type": "STATE", "shape": list(features[STATE_KEY]["shape"])}}
    for key in CAMERA_KEYS:
        h, w, c = features[key]["shape"]
        inputs[key] = {"type": "VISUAL", "shape": [c, h, w]}
    return inputs


def env_args(info: dict, collect: dict) -> list[str]:
    """``--env.*`` options of the in-training evaluation: the dataset's task and settings."""
    from lerobot.envs.configs import EnvConfig
    from lerobot.utils.import_utils import register_third_party_plugins

    settings = collect["settings"]
    env_type = f"wirecraft_{settings['task']}"
    register_third_party_plugins()
    try:
        cls = EnvConfig.get_choice_class(env_type)
    except KeyError:
        raise RuntimeError(
            f"LeRobot does not know --env.type={env_type}: install the plug-in "
            "(pip install -e plugins/lerobot_env_wirecraft)"
        ) from None
    fields = {f.name for f in dataclasses.fields(cls)}
    args = [f"--env.type={env_type}", f"--env.fps={info['fps']}"]
    args.append(f"--env.image_size={settings['image_size']}")
    env_kwargs = settings.get("env_kwargs", {})
    for key, value in sorted(env_kwargs.items()):
        # The control mode is the policy's action's (below), not necessarily the expert's.
        if key in fields and key != "control" and value is not None:
            args.append(f"--env.{key}={value}")
    if dataset_action(collect) == "env":
        # The policy commands the environment in the dataset's control mode; the plug-in's
        # default action type is the joint targets.
        args += ["--env.action_type=env", f"--env.control={env_kwargs['control']}"]
    return args


def dataset_action(collect: dict) -> str:
    """What the dataset's ``action`` holds (``schema.ACTION_KINDS``; older datasets: joint)."""
    return collect.get("settings", {}).get("action", "joint")


# -- options ------------------------------------------------------------------------------------
def parse_pairs(flag: str, items: list[str]) -> dict[str, str]:
    pairs = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            raise usage(flag, f"expected KEY=VALUE, got {item!r}")
        pairs[key.strip()] = value
    return pairs


def policy_fields(algorithm: str) -> set[str] | None:
    """The options of LeRobot's policy config (None: LeRobot cannot say)."""
    try:
        import lerobot.policies  # noqa: F401  (registers the policy configs)
        from lerobot.configs.policies import PreTrainedConfig

        cls = PreTrainedConfig.get_choice_class(algorithm)
    except (ImportError, KeyError):
        return None
    return {f.name for f in dataclasses.fields(cls) if f.init}


def check_policy_args(algorithm: str, pairs: dict[str, str]) -> None:
    known = policy_fields(algorithm)
    for key in pairs:
        if key in RESERVED_POLICY_KEYS:
            raise usage("--policy-arg", f"{key} is set by {RESERVED_POLICY_KEYS[key]}")
        if known is not None and key not in known:
            raise usage(
                "--policy-arg",
                f"LeRobot's {algorithm} policy has no option {key!r} "
                f"(options: {', '.join(sorted(known))})",
            )


def check_train_args(pairs: dict[str, str]) -> None:
    from lerobot.configs.train import TrainPipelineConfig

    known = {f.name for f in dataclasses.fields(TrainPipelineConfig) if f.init}
    for key in pairs:
        head = key.split(".")[0]
        reserved = RESERVED_TRAIN_KEYS.get(key) or RESERVED_TRAIN_KEYS.get(head)
        if reserved:
            raise usage("--train-arg", f"{key} is set by {reserved}")
        if head not in known:
            raise usage(
                "--train-arg",
                f"lerobot-train has no option {key!r} (options: {', '.join(sorted(known))})",
            )


def backbone_file(path: str | Path) -> Path:
    """The torchvision ImageNet ResNet-18 state dict named by ``--pretrained``: the file, or
    in a folder (a torch hub cache or a copy) the file of torchvision's name."""
    path = Path(path)
    if path.is_dir():
        for candidate in (path / RESNET18_FILE, path / "hub" / "checkpoints" / RESNET18_FILE):
            if candidate.is_file():
                path = candidate
                break
        else:
            raise usage(
                "--pretrained", f"{path} holds no {RESNET18_FILE} (torchvision's ResNet-18)"
            )
    elif not path.is_file():
        raise usage("--pretrained", f"{path} does not exist")
    digest = hashlib.sha256(path.read_bytes()).hexdigest()
    want = RESNET18_FILE.split("-")[1].split(".")[0]
    if not digest.startswith(want):
        raise usage(
            "--pretrained",
            f"{path} is not torchvision's ImageNet ResNet-18 ({RESNET18_FILE}: sha256 {want}...), "
            "the only backbone weights LeRobot's ACT / Diffusion load",
        )
    return path


def torch_home_with(weights: Path) -> str:
    """A torch hub cache holding ``weights`` under torchvision's name: torchvision loads it
    from there and downloads nothing."""
    home = Path(tempfile.mkdtemp(prefix="wirecraft_torch_home_"))
    target = home / "hub" / "checkpoints" / RESNET18_FILE
    target.parent.mkdir(parents=True)
    target.symlink_to(weights.resolve())
    return str(home)


def offline_env(torch_home: str | None = None) -> dict:
    env = dict(os.environ)
    env.update(HF_HUB_OFFLINE="1", HF_DATASETS_OFFLINE="1", TRANSFORMERS_OFFLINE="1")
    env.setdefault("WANDB_MODE", "disabled")
    if torch_home:
        env["TORCH_HOME"] = torch_home
    return env


# SmolVLA and pi0.5 build their vision-language backbone and tokenizer through transformers'
# ``from_pretrained`` on names their checkpoint records (even with random weights: SmolVLA's
# ``load_vlm_weights=false`` still loads the backbone's config and processor).  Offline, each
# must be a local folder or already in the Hugging Face cache.
PREPROCESSOR_FILE = "policy_preprocessor.json"


def hub_cache_dir() -> str | None:
    """The Hugging Face hub cache the child process will read (None: the library's default)."""
    if os.environ.get("HF_HUB_CACHE"):
        return os.environ["HF_HUB_CACHE"]
    if os.environ.get("HF_HOME"):
        return str(Path(os.environ["HF_HOME"]) / "hub")
    return None


def backbone_references(folder: str | Path) -> list[tuple[str, str, str]]:
    """(what, name, a file it must have) for each backbone the checkpoint in ``folder`` loads
    by name: the VLM of SmolVLA (``vlm_model_name`` in config.json: its config and processor)
    and the tokenizer of the pre-processor (``tokenizer_name`` in policy_preprocessor.json)."""
    folder = Path(folder)
    refs = []
    try:
        config = json.loads((folder / "config.json").read_text())
    except (OSError, json.JSONDecodeError):
        config = {}
    if config.get("vlm_model_name"):
        refs.append(("vlm_model_name in config.json", config["vlm_model_name"], "config.json"))
    try:
        steps = json.loads((folder / PREPROCESSOR_FILE).read_text()).get("steps", [])
    except (OSError, json.JSONDecodeError, AttributeError):
        steps = []
    for step in steps:
        name = (step.get("config") or {}).get("tokenizer_name") if isinstance(step, dict) else None
        if name:
            refs.append((f"tokenizer_name in {PREPROCESSOR_FILE}", name, "tokenizer_config.json"))
    return refs


def is_available_offline(name: str, filename: str) -> bool:
    """Whether ``from_pretrained(name)`` finds ``filename`` without the hub: a local folder,
    or a hub repository id already in the cache."""
    if Path(name).is_dir():
        return True
    try:
        from huggingface_hub import try_to_load_from_cache

        found = try_to_load_from_cache(name, filename, cache_dir=hub_cache_dir())
    except Exception:  # not a repository id (a path that does not exist, ...)
        return False
    return isinstance(found, str)


def check_backbones(folder: str | Path, flag: str = "--pretrained") -> None:
    """A usage error naming each backbone the checkpoint loads by a name that resolves neither
    to a local folder nor to the Hugging Face cache (WireCraft runs LeRobot offline)."""
    missing = [
        f"{what} = {name!r}"
        for what, name, filename in backbone_references(folder)
        if not is_available_offline(name, filename)
    ]
    if missing:
        raise usage(
            flag,
            f"{folder} loads {'; '.join(missing)}: neither a local folder nor in the Hugging "
            "Face cache, and WireCraft downloads nothing (HF_HUB_OFFLINE=1). Download it "
            "beforehand (huggingface-cli download NAME) or point the name at a local copy",
        )


# -- runs ---------------------------------------------------------------------------------------
def last_step(out: str | Path) -> int | None:
    """The step of the run's last checkpoint, or None when it has none."""
    state = Path(out) / LAST_CHECKPOINT / "training_state" / "training_step.json"
    try:
        return int(json.loads(state.read_text())["step"])
    except (OSError, ValueError, KeyError, TypeError):
        return None


def is_run(out: str | Path) -> bool:
    return (Path(out) / LAST_CHECKPOINT / "pretrained_model" / TRAIN_CONFIG).is_file()


def read_record(out: str | Path) -> dict:
    try:
        return json.loads((Path(out) / RUN_FILE).read_text())
    except (OSError, json.JSONDecodeError):
        return {}


def _write_record(out: Path, record: dict) -> None:
    from wirecraft.cli_args import write_json

    write_json(out / RUN_FILE, record)


def fresh_command(
    algorithm: str,
    dataset: str | Path,
    out: str | Path,
    *,
    steps: int | None = None,
    batch_size: int | None = None,
    device: str | None = None,
    preset: str | None = None,
    policy_args: dict[str, str] | None = None,
    train_args: dict[str, str] | None = None,
    pretrained: str | Path | None = None,
) -> tuple[list[str], dict]:
    """(lerobot-train arguments, a summary of the settings) for a new run; every check of the
    input happens here, before anything is written."""
    if algorithm not in ALGORITHMS:
        raise usage("algorithm", f"unknown {algorithm!r}; valid: {', '.join(ALGORITHMS)}")
    if algorithm in FINE_TUNE_ONLY and pretrained is None:
        raise usage(
            "--pretrained",
            f"{algorithm} is fine-tuned from a local checkpoint folder: pass --pretrained PATH "
            "(WireCraft downloads no weights)",
        )
    if Path(out).exists():
        raise usage(
            "--out", f"{out} exists: --resume continues the run in it, or name a new folder"
        )
    info, collect = read_dataset(dataset)
    policy_args = dict(policy_args or {})
    train_args = dict(train_args or {})
    check_policy_args(algorithm, policy_args)
    check_train_args(train_args)
    dataset_root = Path(dataset).resolve()
    args = [
        "--dataset.repo_id=wirecraft/local",
        f"--dataset.root={dataset_root}",
        "--dataset.video_backend=pyav",
        f"--output_dir={Path(out).resolve()}",
        "--wandb.enable=false",
        *env_args(info, collect),
        # LeRobot's default (50 environments at once) is too many for a CPU.
        "--eval.n_episodes=8",
        "--eval.batch_size=2",
    ]
    settings: dict = {"pretrained": None}
    if algorithm in FINE_TUNE_ONLY:
        folder = Path(pretrained)
        if not (folder / "config.json").is_file():
            raise usage(
                "--pretrained", f"{pretrained} is not a LeRobot checkpoint folder (no config.json)"
            )
        check_backbones(folder)
        args.append(f"--policy.path={folder.resolve()}")
        settings["pretrained"] = str(folder.resolve())
        policy = {}
        torch_home = None
    else:
        reference = REFERENCE[algorithm]
        chosen = PRESETS[preset][algorithm] if preset else reference
        policy = {**reference["policy"], **chosen["policy"]}
        steps = steps or chosen["steps"]
        batch_size = batch_size or chosen["batch_size"]
        args.append(f"--policy.type={algorithm}")
        torch_home = None
        if pretrained is None:
            policy["pretrained_backbone_weights"] = "null"
            if algorithm == "diffusion":
                # Diffusion Policy's recipe for a backbone trained from scratch.
                policy["use_group_norm"] = "true"
        else:
            weights = backbone_file(pretrained)
            policy["pretrained_backbone_weights"] = "ResNet18_Weights.IMAGENET1K_V1"
            if algorithm == "diffusion":
                policy["use_group_norm"] = "false"  # LeRobot: no group norm with weights
            settings["pretrained"] = str(weights.resolve())
            torch_home = torch_home_with(weights)
    policy.update(policy_args)
    args.append("--policy.push_to_hub=false")
    args.append(f"--policy.input_features={json.dumps(input_features(info))}")
    if device:
        args.append(f"--policy.device={device}")
    args += [f"--policy.{k}={v}" for k, v in policy.items()]
    if steps:
        args.append(f"--steps={int(steps)}")
    if batch_size:
        args.append(f"--batch_size={int(batch_size)}")
    args += [f"--{k}={v}" for k, v in train_args.items()]
    settings.update(
        algorithm=algorithm,
        dataset=str(dataset_root),
        dataset_collect={k: collect.get(k) for k in ("settings", "source", "state_revision")},
        dataset_provenance=collect.get("provenance"),
        dataset_episodes=info.get("total_episodes"),
        dataset_frames=info.get("total_frames"),
        fps=info.get("fps"),
        action=dataset_action(collect),
        preset=preset,
        policy=policy,
        steps=steps,
        batch_size=batch_size,
        torch_home=torch_home,
    )
    return args, settings


def resume_command(
    out: str | Path, *, steps: int | None = None, train_args: dict[str, str] | None = None
) -> tuple[list[str], dict]:
    """(lerobot-train arguments, settings) continuing the run in ``out`` from its last
    checkpoint (LeRobot's resume: the saved config, optimizer, scheduler and step)."""
    if not Path(out).exists():
        raise usage("--resume", f"{out} does not exist: nothing to resume")
    if not is_run(out):
        raise usage(
            "--resume",
            f"{out} holds no LeRobot checkpoint ({LAST_CHECKPOINT}/pretrained_model/"
            f"{TRAIN_CONFIG}): nothing to resume",
        )
    train_args = dict(train_args or {})
    check_train_args(train_args)
    done = last_step(out)
    config = Path(out).resolve() / LAST_CHECKPOINT / "pretrained_model" / TRAIN_CONFIG
    total = steps or json.loads(config.read_text()).get("steps")
    if done is not None and total is not None and int(total) <= done:
        raise usage(
            "--steps",
            f"the run in {out} is at step {done}: pass a larger --steps to continue it",
        )
    args = [f"--config_path={config}", "--resume=true"]
    if steps:
        args.append(f"--steps={int(steps)}")
    args += [f"--{k}={v}" for k, v in train_args.items()]
    record = read_record(out)
    if record.get("algorithm") in FINE_TUNE_ONLY:
        check_backbones(config.parent, "--resume")
    torch_home = None
    if record.get("pretrained") and record.get("algorithm") in TRAINABLE:
        torch_home = torch_home_with(backbone_file(record["pretrained"]))
    return args, {"resumed_from_step": done, "steps": total, "torch_home": torch_home}


def run_lerobot_train(args: list[str], env: dict) -> int:
    """``lerobot-train`` in a child process (its log is the progress); its exit status."""
    command = [sys.executable, "-m", "lerobot.scripts.lerobot_train", *args]
    try:
        return subprocess.run(command, env=env, check=False).returncode
    except KeyboardInterrupt:
        return 130


def train(
    algorithm: str,
    dataset: str | Path | None,
    out: str | Path,
    *,
    resume: bool = False,
    command: list[str] | None = None,
    **options,
) -> dict:
    """Train (or with ``resume`` continue) an imitation policy in ``out``; returns the record
    written to ``out/wirecraft_il.json``."""
    from wirecraft.provenance import provenance

    out = Path(out)
    torch_threads = options.pop("torch_threads", None)
    if torch_threads is not None and (
        isinstance(torch_threads, bool) or not isinstance(torch_threads, int) or torch_threads < 1
    ):
        raise usage("torch_threads", f"must be an integer >= 1, got {torch_threads!r}")
    if resume:
        record = read_record(out)
        if record.get("algorithm") not in (None, algorithm):
            raise usage("algorithm", f"{out} holds a {record['algorithm']} run, not {algorithm}")
        args, settings = resume_command(
            out, steps=options.get("steps"), train_args=options.get("train_args")
        )
    else:
        args, settings = fresh_command(algorithm, dataset, out, **options)
        record = {
            k: v for k, v in settings.items() if k not in ("torch_home", "steps", "batch_size")
        }
        record["sessions"] = []
    torch_home = settings.pop("torch_home", None)
    session = {
        "command": command,
        "lerobot_train": args,
        "resumed_from_step": settings.get("resumed_from_step"),
        "steps": settings.get("steps"),
        "torch_threads": torch_threads,
        "provenance": provenance(),
    }
    env = offline_env(torch_home)
    if torch_threads:
        # Torch's default, one intra-op thread per core, oversubscribes the cores next to other
        # busy processes (docs/lerobot.md measures what that costs).
        env.update(OMP_NUM_THREADS=str(torch_threads), MKL_NUM_THREADS=str(torch_threads))
    start = time.time()
    try:
        code = run_lerobot_train(args, env)
    finally:
        if out.is_dir():
            session.update(
                exit_code=locals().get("code"),
                wall_time_s=round(time.time() - start, 1),
                last_step=last_step(out),
            )
            record.setdefault("sessions", []).append(session)
            _write_record(out, record)
        if torch_home:
            import shutil

            shutil.rmtree(torch_home, ignore_errors=True)
    if code != 0:
        raise RuntimeError(f"lerobot-train exited with status {code} (its log is above)")
    return record
