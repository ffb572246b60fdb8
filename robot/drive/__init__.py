"""The only callers of a robot env's moves: the robot's own process (process.py), the actor loop it runs for a
learner (actor.py), and the actor's end of their link (link.py)."""
