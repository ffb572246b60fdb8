"""The policies a run keeps beside its checkpoint for export: the last evaluated one and the best evaluated one."""

from pathlib import Path
from typing import Any

import numpy as np

from contract.checkpoint_location import BEST_POLICY_FILENAME, LAST_EVAL_POLICY_FILENAME, POLICIES_INDEX, sibling
from learner.checkpoint import load_json, save_checkpoint, save_json


def keep_evaluated_policy(checkpoint_file: Path | str, policy: dict[str, Any], step: int, episodes: list[Any]) -> None:
    """The policy this evaluation ran (no update ran since its episodes), as policy-last-eval.pt, and as
    policy-best.pt when it scored best so far (success rate, then return), each with its step and score in the
    file and in policies.json: the export offers the policy whose score the run page showed."""
    successes = [episode.success for episode in episodes]
    score = {
        "step": step,
        "success_rate": float(np.mean(successes)) if all(s is not None for s in successes) else None,
        "return": float(np.mean([episode.total for episode in episodes])),
    }
    state = {**policy, **score}
    index_location = sibling(checkpoint_file, POLICIES_INDEX)
    index = load_json(index_location) or {}
    save_checkpoint(sibling(checkpoint_file, LAST_EVAL_POLICY_FILENAME), state)
    index["last_eval"] = {"file": LAST_EVAL_POLICY_FILENAME, **score}

    def rank(entry: dict[str, Any]) -> tuple[float, float]:
        rate = entry.get("success_rate")
        return (-1.0 if rate is None else rate, entry.get("return") or 0.0)

    best = index.get("best")
    if best is None or rank(score) > rank(best):  # (an equal score keeps the earlier policy)
        save_checkpoint(sibling(checkpoint_file, BEST_POLICY_FILENAME), state)
        index["best"] = {"file": BEST_POLICY_FILENAME, **score}
    save_json(index_location, index)
