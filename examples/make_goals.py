"""Ten goal photos of examples/my_robot.py: the block on the mark (goal0.png … goal9.png)."""

import my_robot
import numpy as np
from PIL import Image

env = my_robot.Slide()
for i in range(10):
    env.pos = my_robot.MARK + np.random.uniform(-0.02, 0.02, 2)
    Image.fromarray(env.draw(256)).save(f"goal{i}.png")
