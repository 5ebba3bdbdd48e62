"""rwalk-train's console: one progress line per checkpoint chunk, rwalk's, counting the
training's iterations; rsl-rl's report of each iteration ("Learning iteration <it>/<end of
the learn() call>" and an ETA to that end) is not printed."""

import re

from test_train_safety import TINY

from rwalk.runners import train


def test_a_chunked_training_prints_one_progress_line_per_chunk(tmp_path, capsys):
    # --save-interval 2: chunks of iterations 0, 1-2 and 3
    train.main([*TINY, "--log-dir", str(tmp_path / "run"), "--max-iterations", "4",
                "--save-interval", "2"])  # fmt: skip
    out = capsys.readouterr().out
    assert re.findall(r"\[rwalk\] iteration (\d+)/4,", out) == ["1", "3", "4"]
    assert "Learning iteration" not in out
    assert out.count("ETA") == 3, out
