"""The paper's DDPG settings (section 4.3), in a module light enough for the config layer.

``imix_cli.running.config.ddpg`` validates ``algo=ddpg`` runs against these and ``imix_cli.core.ddpg.agent``
builds the agent from them; ``conf/algo/ddpg.yaml`` ships the same values (tests/test_ddpg.py
keeps the three equal).
"""

#: actor/critic hidden layers, the two Adam learning rates, soft-update tau, discount, replay and
#: Ornstein-Uhlenbeck noise settings.
PAPER_SETTINGS = {
    "actor_arch": [8, 8],
    "critic_arch": [16, 16],
    "actor_lr": 0.005,
    "critic_lr": 0.01,
    "tau": 0.001,
    "gamma": 0.99,
    "batch_size": 64,
    "buffer_size": 1_000_000,
    "learning_starts": 100,
    "train_freq": 1,
    "gradient_steps": 1,
    "ou_sigma": 0.2,
    "ou_theta": 0.15,
    "ou_dt": 0.01,
}
