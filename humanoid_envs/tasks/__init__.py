"""One module per task: its scene objects, reset, observation, reward and termination."""
