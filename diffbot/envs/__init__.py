"""Gymnasium and PettingZoo environments on the plant's own code (docs/learning.md).

Importing this package registers them::

    import gymnasium, diffbot.envs
    env = gymnasium.make("diffbot/Avoid-v0")                  # in-process (fast)
    env = gymnasium.make("diffbot/Avoid-v0", transport="bus")  # a lockstep plant over Zenoh
    env = gymnasium.make("diffbot.envs:diffbot/Follow-v0")    # imports this package itself
    envs = gymnasium.make_vec("diffbot/Avoid-v0", num_envs=16,  # N worlds in one process
                              vectorization_mode="vector_entry_point")

    from diffbot.envs import swarm_v0
    penv = swarm_v0.parallel_env(n_robots=4)                   # PettingZoo ParallelEnv
    venv = swarm_v0.vector_env(num_worlds=8, n_robots=4)       # 8 of them: (8, 4, ...) arrays

    from diffbot.envs.sb3 import AvoidVecEnv                   # the batch as an SB3 VecEnv
    venv = AvoidVecEnv(16, normalize_actions=True)

gymnasium and pettingzoo are the ``learn`` extra, Stable-Baselines3 the ``sb3`` one (``make
setup`` installs both); nothing outside this package imports them.
"""
from gymnasium import register

register(id="diffbot/Avoid-v0", entry_point="diffbot.envs.avoid:AvoidEnv",
         vector_entry_point="diffbot.envs.vector:AvoidVectorEnv", max_episode_steps=300)
register(id="diffbot/Follow-v0", entry_point="diffbot.envs.follow:FollowEnv",
         max_episode_steps=750)
