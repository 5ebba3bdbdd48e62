"""Command-line runners: training, evaluation, benchmarks and report figures.

Installed as console scripts (``rwalk-train``, ``rwalk-play``, ``rwalk-bench``,
...); ``python -m rwalk.runners.<name>`` and, in a checkout,
``python -m runners.<name>`` run the same ``main``.
"""
