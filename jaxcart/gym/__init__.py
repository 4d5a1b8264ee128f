"""jaxcart's Gymnasium front-ends (:mod:`jaxcart.gym.adapter`, which re-exports them from
:mod:`jaxcart.gym.single_env` and :mod:`jaxcart.gym.vector_env`, over the compiled programs of
:mod:`jaxcart.gym.kernels`) and GIF rendering (:mod:`jaxcart.gym.render`).

This ``__init__`` only registers ``jaxcart/CartPole-v1`` with Gymnasium, with string entry
points, so ``import jaxcart`` stays cheap: it imports neither Gymnasium nor JAX. Registration
happens as soon as Gymnasium is imported, before or after jaxcart.
"""

from __future__ import annotations

import importlib.util
import sys
import warnings

ENV_ID = "jaxcart/CartPole-v1"


def register() -> None:
    """Registers ``jaxcart/CartPole-v1`` with Gymnasium (single and vector entry points, the
    ``TimeLimit`` and reward threshold of ``CartPole-v1``); idempotent."""
    import gymnasium

    if ENV_ID in gymnasium.registry:
        return
    gymnasium.register(
        id=ENV_ID,
        entry_point="jaxcart.gym.single_env:JaxCartPoleEnv",
        vector_entry_point="jaxcart.gym.vector_env:JaxCartPoleVectorEnv",
        max_episode_steps=500,
        reward_threshold=475.0,
    )


class _RegisteringLoader:
    """Gymnasium's own loader, which then registers jaxcart's env."""

    def __init__(self, loader) -> None:
        self.loader = loader

    def create_module(self, spec):
        return self.loader.create_module(spec)

    def exec_module(self, module) -> None:
        # The module keeps Gymnasium's loader, as if this one had never been there.
        module.__loader__ = module.__spec__.loader = self.loader
        self.loader.exec_module(module)
        try:
            register()
        except Exception as error:  # a failed registration must not fail Gymnasium's import
            warnings.warn(f"jaxcart could not register {ENV_ID}: {error!r}", stacklevel=2)


class _GymnasiumImportHook:
    """A ``sys.meta_path`` finder that finds nothing itself: it hands ``gymnasium``'s spec,
    found by the other finders, a :class:`_RegisteringLoader`, then removes itself."""

    def find_spec(self, fullname, path=None, target=None):
        if fullname != "gymnasium":
            return None
        sys.meta_path.remove(self)
        spec = importlib.util.find_spec(fullname)
        if spec is not None and spec.loader is not None:
            spec.loader = _RegisteringLoader(spec.loader)
        return spec


def register_when_gymnasium_loads() -> None:
    """Registers at once if Gymnasium is already imported, otherwise just after its import
    (a ``sys.meta_path`` hook that imports nothing itself); idempotent."""
    if "gymnasium" in sys.modules:
        register()
    elif not any(isinstance(f, _GymnasiumImportHook) for f in sys.meta_path):
        sys.meta_path.insert(0, _GymnasiumImportHook())
