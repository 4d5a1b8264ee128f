"""One module per training-speed contender, each with ``run(preset_name, num_seeds, quick,
cache_dir) -> (data, greedy policy)``, run inside the contender's own process (and, for rejax
and sbx, virtualenv)."""
