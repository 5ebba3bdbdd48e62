"""Weights & Biases for rwalk-train (--logger wandb): rsl-rl's own writer, one W&B run
per training.

rsl-rl builds its writer at each ``learn()`` call, and rwalk-train calls ``learn()``
once per checkpoint chunk (``rwalk.rl.training._learn``); rsl-rl's
``WandbLogWriter`` would start a new W&B run at each and end it at the chunk's end.
This writer starts one at the first chunk, names it (--run-name) and keeps logging
into it; ``finish`` ends it with the training. The TensorBoard event files are written as well.
"""

from __future__ import annotations

from rsl_rl.utils.wandb_log_writer import WandbLogWriter, wandb
from torch.utils.tensorboard import SummaryWriter

MISSING = "--logger wandb needs the wandb package: pip install 'rwalk[wandb]' (or wandb)"


def available() -> bool:
    return wandb is not None


class WandbWriter(WandbLogWriter):
    """rsl-rl's ``WandbLogWriter`` that goes on with the process's active W&B run.

    Args:
        log_dir: the run folder (rsl-rl's writers' first argument).
        project_name: the W&B project.
        run_name: the W&B run's name ("" = the folder's name, as rsl-rl names it).
    """

    def __init__(self, log_dir: str, project_name: str, run_name: str = "") -> None:
        if wandb is None:
            raise ModuleNotFoundError(MISSING)
        if wandb.run is None:  # the training's first chunk
            super().__init__(log_dir, project_name)
            if run_name:
                wandb.run.name = run_name
        else:  # a later chunk: the same W&B run, a fresh TensorBoard writer
            SummaryWriter.__init__(self, log_dir, flush_secs=10)
            self.logged_videos = set()

    def store_config(self, env_cfg: dict, train_cfg: dict) -> None:
        """The env's and the training's configs as the W&B run's config (rwalk's env config
        is a dict, which rsl-rl's writer cannot store; every chunk stores the same)."""
        wandb.config.update({"train_cfg": train_cfg, "env_cfg": env_cfg}, allow_val_change=True)

    def stop(self) -> None:
        """The end of a ``learn()`` chunk: close the TensorBoard file and keep the W&B run
        (rsl-rl's writer would end it here; ``finish`` does, with the training)."""
        SummaryWriter.close(self)

    @staticmethod
    def finish() -> None:
        """End the training's W&B run (at its end; a no-op without one)."""
        if wandb is not None and wandb.run is not None:
            wandb.finish()
