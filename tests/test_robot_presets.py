"""The robot presets: the paper's real-robot settings stay the paper's, and the CPU preset differs from them only
in the networks' size (the simulated tasks' 48 px and 8 filters) and in fitting more of those small updates in
each robot step."""

from dataclasses import asdict

from contract.config import TrainConfig


def test_the_cpu_robot_preset_is_the_papers_with_small_networks_and_more_updates() -> None:
    paper, cpu = TrainConfig.real_robot(), TrainConfig.cpu_robot()
    assert (paper.image_size, paper.conv_filters) == (84, 32)
    assert (cpu.image_size, cpu.conv_filters) == (48, 8)
    assert (cpu.query_every, cpu.query_budget, cpu.eval_episodes) == (250, 50, 0)
    differ = {name for name, value in asdict(cpu).items() if asdict(paper)[name] != value}
    assert differ == {"image_size", "conv_filters", "updates_per_step"}
    assert (paper.updates_per_step, cpu.updates_per_step) == (2, 4)
    assert TrainConfig.cpu_robot(seed=3).seed == 3
