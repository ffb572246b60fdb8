"""The GPU path's parts on the CPU (CI has no GPU): the device replay mirror, its sampling and random shift, the
rewards computed per batch, the device classifier step and metric sums. tests/test_gpu.py runs the CUDA graphs."""

import numpy as np
import pytest
import torch

from contract.algorithms import ALGORITHM_SPECS
from contract.config import TrainConfig
from learner.device_replay import DeviceReplay
from learner.replay import ReplayBuffer, edge_pad
from learner.reward import RewardModel, mixup
from learner.sac import SACAgent
from learner.updates import DeviceExamples, DeviceUpdates, HostUpdates, MetricSums, make_updates

torch.set_num_threads(1)
SIZE = 16
CPU = torch.device("cpu")


def tiny(**overrides: object) -> TrainConfig:
    values: dict[str, object] = dict(
        image_size=SIZE, conv_filters=4, hidden_dim=32, batch_size=16, classifier_batch_size=8, precision="fp32",
        replay_capacity=50, query_budget=3,
    )  # fmt: skip
    values.update(overrides)
    return TrainConfig(**values)  # type: ignore[arg-type]


def filled(replay: ReplayBuffer, transitions: int, rng: np.random.Generator, episode: int = 7) -> None:
    """Episodes of `episode` steps of random frames, with a reset frame at each start."""
    slot = replay.add_frame(rng.integers(0, 256, (SIZE, SIZE, 3), dtype=np.uint8))
    for index in range(transitions):
        next_slot = replay.add_frame(rng.integers(0, 256, (SIZE, SIZE, 3), dtype=np.uint8))
        replay.add(slot, rng.uniform(-1, 1, 2).astype(np.float32), next_slot, index % 5 == 4, float(index % 3 == 0))
        slot = next_slot
        if index % episode == episode - 1:
            slot = replay.add_frame(rng.integers(0, 256, (SIZE, SIZE, 3), dtype=np.uint8))


def test_device_replay_mirrors_the_host_buffer_through_a_ring_wrap() -> None:
    rng = np.random.default_rng(0)
    replay = ReplayBuffer(50, (SIZE, SIZE, 3), 2)
    mirror = DeviceReplay(replay, CPU)
    for count in (10, 30, 45, 40):  # 125 transitions and 145 frames in all: both rings (50 and 102) wrap
        filled(replay, count, rng)
        mirror.sync()
        used = len(replay)
        np.testing.assert_array_equal(mirror.frames.numpy(), replay.frames)
        for name in ("obs_slot", "next_slot", "actions", "not_done"):
            np.testing.assert_array_equal(getattr(mirror, name).numpy()[:used], getattr(replay, name)[:used])
        np.testing.assert_array_equal(mirror.env_reward.numpy()[:used], replay.env_reward[:used])
        assert mirror.size.item() == used and mirror.last_index.item() == used - 1


def test_device_samples_come_from_the_stored_transitions_only() -> None:
    rng = np.random.default_rng(1)
    replay = ReplayBuffer(50, (SIZE, SIZE, 3), 2)
    filled(replay, 9, rng)  # 9 of 50 slots used
    mirror = DeviceReplay(replay, CPU)
    mirror.sync()
    torch.manual_seed(0)
    indices = torch.cat([mirror.sample_indices(256) for _ in range(8)]).numpy()
    assert indices.min() == 0 and indices.max() == 8 and len(np.unique(indices)) == 9
    batch = mirror.sample(64)
    chosen = batch["indices"].numpy()
    np.testing.assert_array_equal(batch["obs"].numpy(), replay.frames[replay.obs_slot[chosen]])
    np.testing.assert_array_equal(batch["next_obs"].numpy(), replay.frames[replay.next_slot[chosen]])
    np.testing.assert_array_equal(batch["action"].numpy(), replay.actions[chosen])
    np.testing.assert_array_equal(batch["not_done"].numpy(), replay.not_done[chosen])
    np.testing.assert_array_equal(batch["env_reward"].numpy(), replay.env_reward[chosen])


def test_device_shift_is_a_drq_crop_of_the_edge_padded_image() -> None:
    rng = np.random.default_rng(2)
    replay = ReplayBuffer(50, (SIZE, SIZE, 3), 2)
    filled(replay, 20, rng)
    mirror = DeviceReplay(replay, CPU)
    mirror.sync()
    pad = 2
    slots = torch.arange(20)
    shifted = mirror.gather(slots, pad).numpy()
    padded = edge_pad(replay.frames[:20], pad)
    seen = set()
    for index in range(20):  # each is exactly one of the (2 pad + 1)^2 crops of its own padded image
        crops = [(dy, dx) for dy in range(2 * pad + 1) for dx in range(2 * pad + 1)
                 if np.array_equal(padded[index, dy : dy + SIZE, dx : dx + SIZE], shifted[index])]  # fmt: skip
        assert crops, f"image {index} is no crop of its padded image"
        seen.add(crops[0])
    assert len(seen) > 3  # offsets are drawn per image
    np.testing.assert_array_equal(mirror.gather(slots, 0).numpy(), replay.frames[:20])


def test_rewards_computed_per_batch_equal_the_host_cache() -> None:
    rng = np.random.default_rng(3)
    torch.manual_seed(3)
    config = tiny(algorithm="vice_raq")
    replay = ReplayBuffer(50, (SIZE, SIZE, 3), 2)
    filled(replay, 40, rng)
    model = RewardModel.for_run(config, rng)
    mirror = DeviceReplay(replay, CPU)
    mirror.sync()
    batch = mirror.sample(32, pad=1)
    on_device = model.logits_on_device(batch["next_obs_unshifted"]).numpy()
    np.testing.assert_allclose(on_device, model.rewards(replay, batch["indices"].numpy()), rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize("algorithm", ["vice_raq", "raq", "sparse"])
def test_device_updates_train_like_host_updates(algorithm: str) -> None:
    """Same metric names, finite values; the SAC networks and (classifier methods) f_psi change; the version
    counts every classifier step, device steps included."""
    rng = np.random.default_rng(4)
    torch.manual_seed(4)
    config = tiny(algorithm=algorithm, replay_pipeline="device")
    spec = ALGORITHM_SPECS[algorithm]
    agent = SACAgent.for_run(config, action_dim=2)
    replay = ReplayBuffer(50, (SIZE, SIZE, 3), 2)
    filled(replay, 30, rng)
    model = RewardModel.for_run(config, rng) if spec.classifier else None
    if model is not None:
        model.goals = rng.integers(0, 256, (4, SIZE, SIZE, 3), dtype=np.uint8)
        model.initial_negatives = rng.integers(0, 256, (6, SIZE, SIZE, 3), dtype=np.uint8)
    updates = make_updates(config, agent=agent, replay=replay, reward_model=model, spec=spec, rng=rng)
    assert isinstance(updates, DeviceUpdates)
    host = HostUpdates(config, agent=agent, replay=replay, reward_model=model, spec=spec, rng=rng)
    actor_before = [p.detach().clone() for p in agent.actor.parameters()]
    for _ in range(3):
        updates.sac_update()
    assert any(not torch.equal(a, p) for a, p in zip(actor_before, agent.actor.parameters(), strict=True))
    for _ in range(3):
        host.sac_update()
    device_metrics, host_metrics = updates.take_metrics(), host.take_metrics()
    assert set(device_metrics) == set(host_metrics)
    assert all(np.isfinite(v) for v in device_metrics.values())
    assert updates.take_metrics() == {}  # taken: a fresh start
    if model is None:
        return
    weights = [p.detach().clone() for p in model.net.parameters()]
    version = model.version
    assert updates.classifier_step(accuracy=False) == {}  # a device step alone moves f_psi
    assert any(not torch.equal(a, p) for a, p in zip(weights, model.net.parameters(), strict=True))
    last = updates.classifier_step(accuracy=True)
    assert model.version == version + 2
    assert {"reward/loss", "reward/acc_goal", "reward/acc_replay"} <= set(last)
    model.add_positive(rng.integers(0, 256, (SIZE, SIZE, 3), dtype=np.uint8))  # an answer: the set grows
    updates.classifier_step(accuracy=False)
    assert updates.positives.synced == 5 and updates.positives.count.item() == 5


def test_device_examples_grow_in_place_until_their_spare_room_is_used() -> None:
    rng = np.random.default_rng(5)
    examples = DeviceExamples(CPU, spare=2)
    images = rng.integers(0, 256, (3, SIZE, SIZE, 3), dtype=np.uint8)
    assert examples.sync(images) is True  # first storage
    storage = examples.images
    grown = np.concatenate([images, rng.integers(0, 256, (2, SIZE, SIZE, 3), dtype=np.uint8)])
    assert examples.sync(grown) is False and examples.images is storage
    np.testing.assert_array_equal(examples.images[:5].numpy(), grown)
    torch.manual_seed(0)
    drawn = examples.sample(400).numpy().reshape(400, -1)
    assert {row.tobytes() for row in drawn} == {image.tobytes() for image in grown}
    assert examples.sync(np.concatenate([grown, grown[:1]])) is True  # past the spare room: new storage


def test_mixup_on_device_mixes_images_and_labels_with_one_lambda() -> None:
    torch.manual_seed(6)
    images = torch.rand(64, 3, 4, 4)
    labels = torch.cat([torch.ones(32), torch.zeros(32)])
    mixed, mixed_labels = mixup(images, labels, 1.0, None)
    assert ((mixed_labels >= 0) & (mixed_labels <= 1)).all() and 0.2 < mixed_labels.mean().item() < 0.8
    assert not torch.equal(mixed, images)
    # each mixed image is lam x_i + (1 - lam) x_j for one j, with its label lam y_i + (1 - lam) y_j
    for index in range(8):
        residuals = []
        for other in range(64):
            if torch.equal(images[other], images[index]):
                continue
            direction = images[index] - images[other]
            lam = ((mixed[index] - images[other]) * direction).sum() / direction.pow(2).sum()
            fit = torch.lerp(images[other], images[index], lam)
            residuals.append(((fit - mixed[index]).abs().max().item(), lam.item(), other))
        error, lam, other = min(residuals)
        assert error < 1e-5
        assert mixed_labels[index].item() == pytest.approx(
            lam * labels[index].item() + (1 - lam) * labels[other].item(), abs=1e-4
        )
    same, same_labels = mixup(images, labels, 0.0, None)
    assert same is images and same_labels is labels


def test_metric_sums_average_floats_and_device_tensors_alike() -> None:
    floats, tensors = MetricSums(), MetricSums()
    for value in (1.0, 2.0, 6.0):
        floats.add({"a": value, "b": -value})
        tensors.add({"a": torch.tensor(value), "b": torch.tensor(-value)})
    assert floats.take() == tensors.take() == {"a": 3.0, "b": -3.0}
    assert floats.take() == {} and tensors.count == 0


def test_no_answers_join_a_share_of_the_vice_raq_negatives_on_host_and_device() -> None:
    """no_answer_share=0.25: before any "no" the negatives are all replay frames; after, the first quarter of each
    batch comes from the answered-no images (host and device alike); at 0 (the paper) none do."""
    rng = np.random.default_rng(7)
    torch.manual_seed(7)
    replay = ReplayBuffer(50, (SIZE, SIZE, 3), 2)
    filled(replay, 30, rng)
    spec = ALGORITHM_SPECS["vice_raq"]
    no_images = np.full((2, SIZE, SIZE, 3), 255, dtype=np.uint8)  # all white: never a random replay frame
    no_images[1, 0, 0] = 0
    for share, expected in ((0.25, 2), (0.0, 0)):
        config = tiny(algorithm="vice_raq", replay_pipeline="device", no_answer_share=share)
        agent = SACAgent.for_run(config, action_dim=2)
        model = RewardModel.for_run(config, rng)
        model.goals = rng.integers(0, 256, (4, SIZE, SIZE, 3), dtype=np.uint8)
        device = DeviceUpdates(config, agent=agent, replay=replay, reward_model=model, spec=spec, rng=rng)
        host = device.host
        device.classifier_step(accuracy=False)  # syncs the (still empty) answered set
        for batch in (host.negatives(), device.negatives_on_device().numpy()):
            assert len(batch) == 8 and not any((image == 255).all() for image in batch)
        for image in no_images:
            model.add_negative(image)
        device.classifier_step(accuracy=False)
        for batch in (host.negatives(), device.negatives_on_device().numpy()):
            from_answers = [i for i, image in enumerate(batch) if any(np.array_equal(image, n) for n in no_images)]
            assert from_answers == list(range(expected))
