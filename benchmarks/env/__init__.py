"""Environment speed: steps/s against gymnax, Gymnasium and EnvPool (``throughput``, with the
harness in ``contenders``), one env step part by part (``step_ablation``) and the Gymnasium
adapter's overhead (``adapter_speed``)."""
