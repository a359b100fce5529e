"""Teachers that act on privileged state: the scripted expert (here) and the PPO teacher."""
