"""Evaluation: the seeded protocol, policies, failure diagnostics, retention, reports.

``evaluate(task, policy_spec, seeds=4, episodes=16, workers=1, **env_kwargs)`` returns the JSON
payload of ``wirecraft eval``; ``run_evaluation`` also returns every episode's trace.  See
docs/evaluation.md.  Names load on first use, so ``wirecraft --help`` stays fast.
"""

from __future__ import annotations

import importlib

_EXPORTS = {
    "taxonomy": "diagnostics",
    "labels_for": "diagnostics",
    "Policy": "policies",
    "load_policy": "policies",
    "policy_env_kwargs": "policies",
    "EvaluationRun": "protocol",
    "evaluate": "protocol",
    "run_evaluation": "protocol",
    "PROTOCOL_VERSION": "seeds",
    "episode_seeds": "seeds",
    "variant_key": "seeds",
}


def __getattr__(name: str):
    if name in _EXPORTS:
        return getattr(importlib.import_module(f"wirecraft.evaluation.{_EXPORTS[name]}"), name)
    raise AttributeError(f"module 'wirecraft.evaluation' has no attribute {name!r}")


__all__ = sorted(_EXPORTS)
