"""SmolVLA and pi0.5 through ``wirecraft train smolvla|pi05 --pretrained`` and ``wirecraft eval``,
offline (nothing comes from the Hugging Face hub):

- a tiny SmolVLA is built with random weights on a tiny vision-language backbone generated
  here (a SmolVLM config, a byte-level tokenizer with SmolVLM's image tokens, an image and
  video processor; ``load_vlm_weights=false``), saved as LeRobot saves a checkpoint, fine-tuned
  2 steps by the wrapper on a 2-episode dataset, and the trained checkpoint plays an episode;
- a checkpoint that loads its backbone or tokenizer by a hub name this machine does not hold
  is refused by the wrapper, naming it, before anything is written (a cached one is accepted);
- pi0.5 cannot be made tiny in LeRobot 0.6 (fixed Gemma widths, ~1.9 B parameters at least)
  and its pre-processor loads the hub tokenizer ``google/paligemma-3b-pt-224``: asserted, so
  that a LeRobot which lifts either shows up here.
"""

from __future__ import annotations

import importlib.util
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("lerobot", reason="LeRobot is not installed (pip install 'wirecraft[il]')")
for _module, _why in (("accelerate", "lerobot-train"), ("transformers", "SmolVLA and pi0.5")):
    if importlib.util.find_spec(_module) is None:
        pytest.skip(f"{_why} needs {_module}: pip install 'wirecraft[il]'", allow_module_level=True)

from wirecraft.cli import main  # noqa: E402

SIZE, FPS, SEED = 32, 10, 7
BIN = Path(sys.executable).parent
QUICK = ["save_freq=2", "log_freq=1", "num_workers=0", "env_eval_freq=0"]
OFFLINE = {"HF_HUB_OFFLINE": "1", "HF_DATASETS_OFFLINE": "1", "TRANSFORMERS_OFFLINE": "1"}
# SmolVLM's special tokens (the names transformers' SmolVLMProcessor reads off the tokenizer).
IMAGE_TOKENS = {
    "fake_image_token": "<fake_token_around_image>",
    "image_token": "<image>",
    "global_image_token": "<global-img>",
    "end_of_utterance_token": "<end_of_utterance>",
    "video_token": "<video>",
}
HUB_VLM = "HuggingFaceTB/SmolVLM2-500M-Video-Instruct"  # SmolVLA's default backbone


def _run(args, cwd, timeout=300, env=None) -> subprocess.CompletedProcess:
    env = dict(os.environ, **OFFLINE, WANDB_MODE="disabled", **(env or {}))
    proc = subprocess.run(
        [str(a) for a in args], cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout
    )
    assert proc.returncode == 0, (
        f"{args[:3]} exited {proc.returncode}:\n{proc.stdout[-3000:]}\n{proc.stderr[-6000:]}"
    )
    return proc


def write_tiny_smolvlm(folder: Path, image_size: int = SIZE) -> Path:
    """A SmolVLM backbone folder as ``from_pretrained`` reads it, made here and tiny: config
    (a 2-layer Llama of width 64, a 1-layer vision encoder of width 32 on ``image_size``
    images), tokenizer (byte-level, no merges: every byte a token, nothing to learn, plus
    SmolVLM's special tokens) and processor (image and video processors at ``image_size``,
    no image splitting).  No weights: SmolVLA builds the backbone with random ones."""
    from tokenizers import Tokenizer, decoders, models, pre_tokenizers
    from transformers import (
        PreTrainedTokenizerFast,
        SmolVLMConfig,
        SmolVLMImageProcessor,
        SmolVLMProcessor,
    )
    from transformers.models.smolvlm.video_processing_smolvlm import SmolVLMVideoProcessor

    folder.mkdir(parents=True, exist_ok=True)
    byte_symbols = sorted(pre_tokenizers.ByteLevel.alphabet())
    core = Tokenizer(models.BPE(vocab={s: i for i, s in enumerate(byte_symbols)}, merges=[]))
    core.pre_tokenizer = pre_tokenizers.ByteLevel(add_prefix_space=False)
    core.decoder = decoders.ByteLevel()
    tokenizer = PreTrainedTokenizerFast(
        tokenizer_object=core,
        pad_token="<pad>",
        unk_token="<unk>",
        bos_token="<|im_start|>",
        eos_token=IMAGE_TOKENS["end_of_utterance_token"],
        extra_special_tokens=IMAGE_TOKENS,
    )
    # Tile markers of split images (unused without splitting, but part of the vocabulary).
    tiles = [f"<row_{r}_col_{c}>" for r in range(1, 5) for c in range(1, 5)]
    tokenizer.add_tokens(tiles, special_tokens=True)
    edge = {"longest_edge": image_size}
    patch, scale = 8, 2  # (32 / 8)^2 = 16 patches, pixel-shuffled 2x2: 4 tokens per image
    processor = SmolVLMProcessor(
        image_processor=SmolVLMImageProcessor(
            do_image_splitting=False, size=edge, max_image_size=edge
        ),
        tokenizer=tokenizer,
        video_processor=SmolVLMVideoProcessor(size=edge, max_image_size=edge),
        image_seq_len=(image_size // patch) ** 2 // scale**2,
    )
    processor.save_pretrained(folder)
    config = SmolVLMConfig(
        vision_config={
            "hidden_size": 32,
            "intermediate_size": 64,
            "num_hidden_layers": 1,
            "num_attention_heads": 2,
            "image_size": image_size,
            "patch_size": patch,
        },
        text_config={
            "model_type": "llama",
            "hidden_size": 64,
            "intermediate_size": 128,
            "num_hidden_layers": 2,
            "num_attention_heads": 4,
            "num_key_value_heads": 2,
            "head_dim": 16,
            "vocab_size": len(tokenizer),
            "max_position_embeddings": 256,
            "pad_token_id": tokenizer.pad_token_id,
            "bos_token_id": tokenizer.bos_token_id,
            "eos_token_id": tokenizer.eos_token_id,
        },
        image_token_id=tokenizer.convert_tokens_to_ids(IMAGE_TOKENS["image_token"]),
        scale_factor=scale,
        pad_token_id=tokenizer.pad_token_id,
    )
    config.save_pretrained(folder)
    return folder


def save_tiny_smolvla(folder: Path, backbone: Path, dataset: Path) -> Path:
    """A randomly initialised, tiny SmolVLA on ``backbone``, saved as LeRobot saves a trained
    one (policy, pre/post-processors, train_config.json naming ``dataset``)."""
    import torch
    from lerobot.configs.types import FeatureType, PolicyFeature
    from lerobot.policies.factory import make_pre_post_processors
    from lerobot.policies.smolvla.configuration_smolvla import SmolVLAConfig
    from lerobot.policies.smolvla.modeling_smolvla import SmolVLAPolicy

    visual = PolicyFeature(type=FeatureType.VISUAL, shape=(3, SIZE, SIZE))
    config = SmolVLAConfig(
        input_features={
            "observation.state": PolicyFeature(type=FeatureType.STATE, shape=(7,)),
            "observation.images.cam_side": visual,
            "observation.images.cam_wrist": visual,
        },
        output_features={"action": PolicyFeature(type=FeatureType.ACTION, shape=(7,))},
        device="cpu",
        push_to_hub=False,
        vlm_model_name=str(backbone),
        load_vlm_weights=False,
        num_vlm_layers=2,
        expert_width_multiplier=0.5,
        resize_imgs_with_padding=(SIZE, SIZE),
        max_state_dim=8,
        max_action_dim=8,
        chunk_size=5,
        n_action_steps=5,
        num_steps=2,
        tokenizer_max_length=16,
    )
    torch.manual_seed(0)
    policy = SmolVLAPolicy(config)
    image_stats = {"mean": torch.full((3, 1, 1), 0.5), "std": torch.full((3, 1, 1), 0.25)}
    stats = {
        "observation.state": {"mean": torch.zeros(7), "std": torch.ones(7)},
        "action": {"mean": torch.zeros(7), "std": torch.full((7,), 0.1)},
        "observation.images.cam_side": image_stats,
        "observation.images.cam_wrist": image_stats,
    }
    pre, post = make_pre_post_processors(config, dataset_stats=stats)
    folder.mkdir(parents=True, exist_ok=True)
    for part in (policy, pre, post):
        part.save_pretrained(folder)
    train = {"dataset": {"repo_id": "wirecraft/local", "root": str(dataset)}, "env": None}
    (folder / "train_config.json").write_text(json.dumps(train))
    return folder


@pytest.fixture(scope="module")
def dataset(quick_dataset):
    """Two scripted insertion episodes written by ``wirecraft collect`` (conftest)."""
    return quick_dataset


@pytest.fixture(scope="module")
def tiny_smolvla(dataset):
    work = dataset.parent
    backbone = write_tiny_smolvlm(work / "tiny_smolvlm")
    return save_tiny_smolvla(work / "tiny_smolvla", backbone, dataset), backbone


def test_the_tiny_backbone_is_generated_not_downloaded(tiny_smolvla):
    _, backbone = tiny_smolvla
    assert {p.name for p in backbone.iterdir()} >= {
        "config.json",
        "tokenizer.json",
        "tokenizer_config.json",
        "processor_config.json",
    }
    assert not list(backbone.glob("*.safetensors"))  # random weights, built by SmolVLA


def test_smolvla_fine_tunes_and_evaluates_offline(tiny_smolvla, dataset, tmp_path):
    checkpoint, backbone = tiny_smolvla
    out = dataset.parent / "smolvla"
    empty_cache = {"HF_HUB_CACHE": str(tmp_path / "hub_cache")}  # nothing from any cache
    proc = _run(
        [
            BIN / "wirecraft", "train", "smolvla", "--dataset", dataset, "--out", out,
            "--pretrained", checkpoint, "--device", "cpu", "--steps", "2", "--batch-size", "2",
            *[x for v in QUICK for x in ("--train-arg", v)],
        ],
        cwd=dataset.parent,
        env=empty_cache,
    )  # fmt: skip
    log = proc.stdout + proc.stderr
    assert "step:2 " in log
    model = out / "checkpoints" / "last" / "pretrained_model"
    config = json.loads((model / "config.json").read_text())
    assert config["type"] == "smolvla" and config["vlm_model_name"] == str(backbone)
    assert config["chunk_size"] == 5  # the tiny checkpoint's settings, fine-tuned
    assert set(config["input_features"]) == {
        "observation.state",
        "observation.images.cam_side",
        "observation.images.cam_wrist",
    }
    record = json.loads((out / "wirecraft_il.json").read_text())
    assert record["algorithm"] == "smolvla"
    assert record["pretrained"] == str(checkpoint.resolve())
    assert f"--policy.path={checkpoint.resolve()}" in record["sessions"][0]["lerobot_train"]
    assert record["sessions"][0]["last_step"] == 2

    result = tmp_path / "eval.json"
    _run(
        [
            BIN / "wirecraft", "eval", "--policy", model, "--episodes", "1", "--seeds", "1",
            "--episode-seconds", "0.2", "--quiet", "--json", result,
        ],
        cwd=tmp_path,
        env=empty_cache,
    )  # fmt: skip
    payload = json.loads(result.read_text())
    assert payload["env_kwargs"]["control"] == "joint"
    assert len(payload["episodes"]) == 1


def _hub_named_copy(checkpoint: Path, folder: Path, name: str) -> Path:
    """The checkpoint, but loading its backbone and tokenizer by the hub name ``name``."""
    shutil.copytree(checkpoint, folder)
    config = json.loads((folder / "config.json").read_text())
    (folder / "config.json").write_text(json.dumps({**config, "vlm_model_name": name}))
    pre = json.loads((folder / "policy_preprocessor.json").read_text())
    for step in pre["steps"]:
        if "tokenizer_name" in step.get("config", {}):
            step["config"]["tokenizer_name"] = name
    (folder / "policy_preprocessor.json").write_text(json.dumps(pre))
    return folder


def _refused(argv, capsys, *needles):
    code = main(argv)
    err = capsys.readouterr().err
    assert code == 2, err
    for needle in needles:
        assert needle in err, err
    return err


def test_a_backbone_neither_local_nor_cached_is_refused(
    tiny_smolvla, dataset, tmp_path, capsys, monkeypatch
):
    from wirecraft.il.train import check_backbones

    checkpoint, _ = tiny_smolvla
    cache = tmp_path / "hub_cache"
    monkeypatch.setenv("HF_HUB_CACHE", str(cache))
    hub_named = _hub_named_copy(checkpoint, tmp_path / "hub_named", HUB_VLM)
    out = tmp_path / "run"
    base = ["train", "smolvla", "--dataset", str(dataset), "--out", str(out)]
    err = _refused(base + ["--pretrained", str(hub_named)], capsys, "--pretrained", HUB_VLM)
    assert "vlm_model_name" in err and "tokenizer_name" in err
    moved = _hub_named_copy(checkpoint, tmp_path / "moved", str(tmp_path / "gone"))
    _refused(base + ["--pretrained", str(moved)], capsys, "--pretrained", "gone")
    assert not out.exists()
    # Once in the Hugging Face cache (as a download leaves it), the same names are accepted.
    repo = cache / ("models--" + HUB_VLM.replace("/", "--"))
    (repo / "refs").mkdir(parents=True)
    (repo / "refs" / "main").write_text("0" * 40)
    snapshot = repo / "snapshots" / ("0" * 40)
    snapshot.mkdir(parents=True)
    for name in ("config.json", "tokenizer_config.json"):
        (snapshot / name).write_text("{}")
    check_backbones(hub_named)


PI05_CHECK = """
import json
from lerobot.configs.types import FeatureType, PolicyFeature
from lerobot.policies.factory import make_pre_post_processors
from lerobot.policies.pi05 import modeling_pi05
from lerobot.policies.pi05.configuration_pi05 import PI05Config

features = dict(
    input_features={"observation.state": PolicyFeature(type=FeatureType.STATE, shape=(7,))},
    output_features={"action": PolicyFeature(type=FeatureType.ACTION, shape=(7,))},
)
out = {}
try:
    PI05Config(paligemma_variant="tiny", device="cpu", **features)
except ValueError as err:
    out["variant"] = str(err)
smallest = modeling_pi05.get_gemma_config("gemma_300m")
out["smallest"] = [smallest.width, smallest.depth]
config = PI05Config(
    paligemma_variant="gemma_300m", action_expert_variant="gemma_300m", device="cpu", **features
)
try:
    make_pre_post_processors(config, dataset_stats=None)
except OSError as err:
    out["tokenizer"] = type(err).__name__
print(json.dumps(out))
"""


def test_pi05_cannot_be_built_tiny_nor_offline_in_this_lerobot(tmp_path):
    """LeRobot 0.6's pi0.5 takes only the Gemma variants gemma_300m and gemma_2b (width 1024 x
    18 layers at least; with the 257 152-token embeddings and SigLIP ~1.9 B parameters), and
    its pre-processor is built on the hub tokenizer google/paligemma-3b-pt-224, which offline
    and uncached cannot load.  Neither can be generated here: no pi0.5 test trains."""
    proc = _run(
        [sys.executable, "-c", PI05_CHECK],
        cwd=tmp_path,
        env={"HF_HUB_CACHE": str(tmp_path / "hub_cache")},
    )
    out = json.loads(proc.stdout.strip().splitlines()[-1])
    assert "Invalid paligemma_variant" in out["variant"]
    assert out["smallest"] == [1024, 18]
    assert out["tokenizer"] == "OSError"


def test_pi05_with_the_hub_tokenizer_is_a_clear_error(dataset, tmp_path, capsys, monkeypatch):
    """A pi0.5 checkpoint as LeRobot records it (config.json; policy_preprocessor.json whose
    tokenizer step names google/paligemma-3b-pt-224) is refused before any work when that
    tokenizer is not in the cache: the wrapper names it instead of lerobot-train failing."""
    from lerobot.policies.pi05.configuration_pi05 import PI05Config

    monkeypatch.setenv("HF_HUB_CACHE", str(tmp_path / "hub_cache"))
    checkpoint = tmp_path / "pi05"
    checkpoint.mkdir()
    PI05Config(device="cpu")._save_pretrained(checkpoint)
    tokenizer_step = {
        "registry_name": "tokenizer_processor",
        "config": {"tokenizer_name": "google/paligemma-3b-pt-224", "max_length": 200},
    }
    (checkpoint / "policy_preprocessor.json").write_text(
        json.dumps({"name": "policy_preprocessor", "steps": [tokenizer_step]})
    )
    out = tmp_path / "run"
    argv = ["train", "pi05", "--dataset", str(dataset), "--out", str(out)]
    _refused(
        argv + ["--pretrained", str(checkpoint)],
        capsys,
        "--pretrained",
        "google/paligemma-3b-pt-224",
        "tokenizer_name",
    )
    assert not out.exists()
