"""Weights & Biases for rwalk-train (--logger wandb): rsl-rl's own writer, one W&B run
per run folder.

rsl-rl builds its writer at each ``learn()`` call, and rwalk-train calls ``learn()``
once per checkpoint chunk (``rwalk.rl.training._learn``); rsl-rl's
``WandbLogWriter`` would start a new W&B run at each and end it at the chunk's end.
This writer starts one at the first chunk, names it (--run-name) and keeps logging
into it; ``finish`` ends it with the training. The TensorBoard event files are written as well.

W&B's own files go to the run folder's ``wandb/`` (or to WANDB_DIR, where it is set),
never to the current directory. The W&B run's id is kept in the run folder (``ID_FILE``):
a training that goes on with the folder's run (--resume) logs into the same W&B run.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

from rsl_rl.utils.wandb_log_writer import WandbLogWriter, wandb
from torch.utils.tensorboard import SummaryWriter

from rwalk.rl.checkpoints import atomic_write_text, checkpoint_files

MISSING = "--logger wandb needs the wandb package: pip install 'rwalk[wandb]' (or wandb)"
ID_FILE = "wandb_run_id.txt"
"""The run folder's file holding its W&B run's id (one line)."""
RUN_ID = re.compile(r"[A-Za-z0-9_-]{1,128}")
"""What an id read back from ID_FILE must look like (W&B's are 8 lowercase letters and digits)."""
RUN_ID_MAX_BYTES = 256
"""The most of ID_FILE read."""


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
        SummaryWriter.__init__(self, log_dir, flush_secs=10)  # a fresh one each chunk
        self.logged_videos = set()
        if wandb.run is None:  # the training's first chunk
            start_run(Path(log_dir), project_name, run_name or Path(log_dir).name)

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


def start_run(folder: Path, project: str, name: str) -> None:
    """Start the W&B run of the run folder ``folder``, its files in ``folder/wandb``: the
    folder's own W&B run (its id from ID_FILE) where the training goes on with the
    folder's run, else a new one, whose id ID_FILE then holds.

    The first chunk starts before the training saves anything, so a checkpoint in the
    folder is the run this training resumes (rwalk-train trains in a folder with
    checkpoints only with --resume, or --overwrite, which deletes them).
    """
    run_id = saved_run_id(folder) if checkpoint_files(folder) else None
    wandb.init(
        project=project,
        entity=os.environ.get("WANDB_USERNAME"),  # as rsl-rl's writer
        name=name,
        config={"log_dir": str(folder)},
        dir=os.environ.get("WANDB_DIR") or str(folder),
        id=run_id,
        resume="allow" if run_id else None,
    )
    if run_id is None:
        atomic_write_text(folder / ID_FILE, f"{wandb.run.id}\n")


def saved_run_id(folder: Path) -> str | None:
    """The W&B run id ``folder``'s ID_FILE holds; None without one, or (said) for a file
    that holds no id."""
    path = folder / ID_FILE
    try:
        with path.open("rb") as file:
            text = file.read(RUN_ID_MAX_BYTES).decode("ascii", "replace").strip()
    except FileNotFoundError:
        return None
    if RUN_ID.fullmatch(text):
        return text
    print(f"[rwalk] {path} holds no W&B run id: the training starts a new W&B run")
    return None
