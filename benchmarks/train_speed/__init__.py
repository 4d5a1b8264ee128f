"""PPO training speed and time to solve against Stable-Baselines3, sbx and rejax:
``python -m benchmarks.train_speed``. Each contender runs in a fresh process (one module per
tool in ``contenders``); ``common`` holds the names and configurations, ``processes`` the
process-per-seed runs of SB3 and sbx, ``report`` the Markdown and plot."""
