"""Your robot behind one small contract: `RobotEnv` (robot/base.py), a camera over OpenCV (robot/camera.py), a
module to copy and fill in (robot/template.py), and the simulated pusher as a stand-in robot (robot/standin.py).

No torch and no database: a robot env is a Gymnasium env the learner makes like any other.
"""
