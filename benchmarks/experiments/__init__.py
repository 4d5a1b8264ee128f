"""The course's CartPole claims as seeded experiments (``python -m benchmarks.experiments``),
Stable-Baselines3's own PPO as a jaxcart run directory (``sb3_reference``) and the search behind
the ``fast`` preset (``fast_preset_search``, written up in ``fast_preset.md``)."""
