"""The RL layer: rsl-rl's adapter and runner, the training's configs, checkpoints as data,
distributed training, and the TorchRL trainer's parts.

The modules load on first use (rsl-rl and torchrl are heavy, and importing torchrl
switches the process's multiprocessing start method): import them by name, e.g.
``from rwalk.rl.config import TrainConfig``.
"""
