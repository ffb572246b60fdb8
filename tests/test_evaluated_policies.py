"""The policy you saw is the policy you get: each evaluation keeps the policy it ran (policy-last-eval.pt) and the
best-scoring one (policy-best.pt), each with its step and success rate; the export offers both, labelled on the run
page, and the downloaded best policy scores in the env what its evaluation recorded."""

from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch
from fastapi.testclient import TestClient
from test_learner_run import create_run, tiny_config

from contract.envs import make_env, success_of
from contract.settings import Settings
from contract.store import RunStatus, Store
from learner.policy import load_policy
from learner.worker import work

torch.set_num_threads(1)


def test_the_exported_best_policy_reproduces_its_recorded_success(
    make_client: Callable[..., TestClient], make_settings: Callable[..., Settings], store: Store, tmp_path: Path
) -> None:
    config = tiny_config(algorithm="sparse", total_steps=300, eval_every=100, eval_episodes=4, checkpoint_every=300)
    run_id = create_run(store, None, config)
    assert work(make_settings(), worker_name="evaluating-learner", once=True) == 0
    assert store.get_run(run_id=run_id).status == RunStatus.FINISHED
    rates = {m.step: m.value for m in store.metrics(run_id=run_id) if m.name == "eval/success_rate"}
    assert sorted(rates) == [100, 200, 300]

    client = make_client()
    policies = client.get(f"/api/runs/{run_id}/policies").json()
    last, best = policies["last_eval"], policies["best"]
    assert last["step"] == 300 and last["success_rate"] == rates[300]
    returns = {m.step: m.value for m in store.metrics(run_id=run_id) if m.name == "eval/return"}
    # the highest success rate, then the highest return (the earliest of equals)
    assert best["step"] == max(sorted(rates), key=lambda step: (rates[step], returns[step]))
    assert rates[best["step"]] == best["success_rate"]

    page = client.get(f"/runs/{run_id}").text  # the run page's export links, labelled with step and success
    assert f'href="/api/runs/{run_id}/policy?which=best"' in page
    assert f"step {best['step']:,}, success {best['success_rate'] * 100:.0f}%" in page
    assert f"step {last['step']:,}, success {last['success_rate'] * 100:.0f}%" in page

    download = client.get(best["url"])
    assert download.status_code == 200
    path = tmp_path / "best.pt"
    path.write_bytes(download.content)
    policy = load_policy(path)
    assert (policy.step, policy.success_rate) == (best["step"], best["success_rate"])

    # its evaluation again, one episode after another, from the same reset seeds
    env = make_env(config.env_id, image_size=config.image_size, display_size=config.rollout_size)
    successes = []
    try:
        for episode in range(config.eval_episodes):
            observation, info = env.reset(seed=config.seed * 100_003 + 1_000_000 + best["step"] + episode)
            for _ in range(config.episode_steps):
                observation, _reward, terminated, truncated, info = env.step(policy.env_action(observation, env))
                if terminated or truncated:
                    break
            successes.append(success_of(info))
    finally:
        env.close()
    assert float(np.mean(successes)) == best["success_rate"]

    last_download = client.get(f"/api/runs/{run_id}/policy", params={"which": "last_eval"})
    (tmp_path / "last.pt").write_bytes(last_download.content)
    assert load_policy(tmp_path / "last.pt").step == 300
    assert client.get(f"/api/runs/{run_id}/policy").status_code == 200  # the checkpoint's policy.pt, as before
