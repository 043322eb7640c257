"""trustnav: trust-aware safe navigation (Ejaz and Inoue), offline on a CPU.

Importing the package registers the Gymnasium environment ``trustnav/Drive-v0`` when gymnasium is
installed (the id names its entry point as a string: the environment's module, and the driving
world, load only at ``gym.make``).
"""

__version__ = "0.1.0"

GYM_ENV_IDS = {"trustnav/Drive-v0": "trustnav.sim.driving.gym_env:DriveEnv"}


def _register_gym_envs() -> None:
    """Register :data:`GYM_ENV_IDS` with gymnasium, if it is installed (each id once)."""
    import importlib.util

    if importlib.util.find_spec("gymnasium") is None:
        return
    from gymnasium.envs.registration import register, registry

    for env_id, entry_point in GYM_ENV_IDS.items():
        if env_id not in registry:
            register(id=env_id, entry_point=entry_point)


_register_gym_envs()
