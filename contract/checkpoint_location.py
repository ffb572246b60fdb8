"""Where a run's checkpoint and exported policy live: a local directory or an fsspec URL (RAQ_CHECKPOINT_URL).

Imports neither torch nor fsspec, so the web server can locate a run's files (policy export, run deletion).
"""

from pathlib import Path

FILENAME = "checkpoint.pt"
POLICY_FILENAME = "policy.pt"  # beside the checkpoint: the actor and its encoder only (learner/policy.py loads it)
# Beside them, the policies the evaluations judged (the same format as policy.pt, with the evaluation's "step",
# "success_rate" and "return" in the file): the one the latest evaluation ran, and the one of the highest success
# rate so far (then the highest return; the return alone for an env without success). POLICIES_INDEX says which
# step and score each holds, for the server to label them without torch.
LAST_EVAL_POLICY_FILENAME = "policy-last-eval.pt"
BEST_POLICY_FILENAME = "policy-best.pt"
POLICIES_INDEX = "policies.json"  # {"last_eval": {"file", "step", "success_rate", "return"}, "best": {…}}
ACTOR_POLICY_FILENAME = "actor-policy.pt"  # the newest pi for an actor on another host (learner/actor_handle.py)


def is_remote(location: Path | str) -> bool:
    """Whether `location` is a URL of another file system than the local one (file:// counts as local)."""
    location = str(location)
    return "://" in location and not location.startswith("file://")


def run_folder(base: Path | str, run_id: int) -> str:
    """The folder of a run's files under `base`: a local directory or an fsspec URL such as s3://bucket/prefix."""
    base = str(base)
    if not is_remote(base):
        return str(Path(base.removeprefix("file://")) / f"run-{run_id}")
    return f"{base.rstrip('/')}/run-{run_id}"


def checkpoint_path(checkpoint_dir: Path | str, run_id: int) -> Path:
    """A run's checkpoint under a local directory."""
    return Path(checkpoint_dir) / f"run-{run_id}" / FILENAME


def checkpoint_url(base: Path | str, run_id: int) -> str:
    """A run's checkpoint under `base`: a local directory or an fsspec URL such as s3://bucket/prefix."""
    if not is_remote(base):
        return str(checkpoint_path(str(base).removeprefix("file://"), run_id))
    return f"{run_folder(base, run_id)}/{FILENAME}"


def sibling(location: Path | str, name: str) -> str:
    """The file called `name` in the same folder as `location` (a path or URL)."""
    location = str(location)
    if is_remote(location):
        return f"{location.rsplit('/', 1)[0]}/{name}"
    return str(Path(location.removeprefix("file://")).with_name(name))
