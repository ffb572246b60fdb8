"""The README's example env: slide the blue block onto the yellow mark, seen from above."""

import gymnasium as gym
import numpy as np

MARK = np.array([0.7, 0.7])


class Slide(gym.Env):
    """Slide the blue block onto the yellow mark, seen from above."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": 10}

    def __init__(self, image_size=48, render_size=256, render_mode=None):
        self.image_size, self.render_size, self.render_mode = image_size, render_size, render_mode
        self.observation_space = gym.spaces.Box(0, 255, (image_size, image_size, 3), np.uint8)
        self.action_space = gym.spaces.Box(-1.0, 1.0, (2,), np.float32)
        self.pos = np.zeros(2)

    def draw(self, size):
        image = np.full((size, size, 3), 40, np.uint8)
        r = size // 10
        for (x, y), colour in ((MARK, (230, 200, 40)), (self.pos, (40, 80, 230))):
            x, y = int(x * size), int(y * size)
            image[y - r : y + r, x - r : x + r] = colour
        return image

    def info(self):
        return {"success": bool(np.linalg.norm(self.pos - MARK) < 0.05)}

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.pos = self.np_random.uniform(0.1, 0.5, 2)
        return self.draw(self.image_size), self.info()

    def step(self, action):
        self.pos = np.clip(self.pos + 0.05 * np.asarray(action), 0.1, 0.9)
        return self.draw(self.image_size), 0.0, False, False, self.info()

    def render(self):
        return self.draw(self.render_size)


if "Slide-v0" not in gym.registry:
    gym.register("Slide-v0", entry_point="my_robot:Slide", max_episode_steps=100)
