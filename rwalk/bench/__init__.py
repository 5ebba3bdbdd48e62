"""The benchmark: the env's throughput and memory beside its physics floor (``rwalk-bench``).

- ``meters``: timing windows, alternating rounds, the Floor (raw ``mujoco.rollout``),
  EnvMeter, peak RSS, robot-seconds per core-second.
- ``modes``: each mode's measurement and the worker that runs one mode in a fresh process.
- ``envpool``: mode (e), rwalk beside EnvPool's Go1 (the optional ``bench`` extra).
- ``report``: the markdown tables, the summary lines and the plot.
- ``single``: one ``ResidualWalkEnv.step`` against its physics floor.

The command lines are ``rwalk.runners.bench`` and ``rwalk.runners.single_bench``.
Nothing is imported here: ``python -m rwalk.bench.modes`` starts a worker without
importing the rest first.
"""
