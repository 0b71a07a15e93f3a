"""Record every transition a vectorised environment produces, one stream per sub-environment.

``RecordingVecEnv`` wraps an SB3 ``VecEnv``; whatever steps it (an SB3 learner, a random policy)
leaves behind, per copy, the ordered stream (s, a, r, s', done) that is one learning history.
Unlike the reference code it logs (docs/design.md section 3):

* the **true final state** at an episode end: SB3 auto-resets and returns the reset state, hiding
  the real s' in ``infos[i]["terminal_observation"]``;
* the **executed** action: continuous envs report the clipped action in ``info["executed_action"]``;
* the oracle's action *before* the step (gridworlds), from the copy's own state.
"""

from __future__ import annotations

import numpy as np
from stable_baselines3.common.vec_env import VecEnv, VecEnvWrapper


class RecordingVecEnv(VecEnvWrapper):
    """Keep the first ``steps`` transitions of each of the ``venv.num_envs`` copies.

    After recording, ``arrays()`` returns (n_envs, steps, ...) arrays.  Steps past ``steps`` (an
    SB3 learner may overshoot to finish its last rollout) pass through unrecorded.
    """

    def __init__(self, venv: VecEnv, steps: int, record_optimal: bool = False) -> None:
        super().__init__(venv)
        n = venv.num_envs
        obs_shape = venv.observation_space.shape
        obs_dtype = venv.observation_space.dtype
        self.steps = steps
        self.record_optimal = record_optimal
        self.obs = np.zeros((n, steps, *obs_shape), dtype=obs_dtype)
        self.next_obs = np.zeros_like(self.obs)
        act_space = venv.action_space
        if act_space.shape == ():
            self.actions = np.zeros((n, steps), dtype=np.int64)
        else:
            self.actions = np.zeros((n, steps, *act_space.shape), dtype=np.float32)
        self.rewards = np.zeros((n, steps), dtype=np.float32)
        self.dones = np.zeros((n, steps), dtype=bool)
        self.optimal = np.zeros((n, steps), dtype=np.int64) if record_optimal else None
        self.success: np.ndarray | None = None  # allocated when the env reports info["success"]
        self.t = 0
        self._last_obs: np.ndarray | None = None
        self._pending_actions: np.ndarray | None = None
        self._pending_optimal: np.ndarray | None = None

    @property
    def full(self) -> bool:
        return self.t >= self.steps

    def reset(self) -> np.ndarray:
        obs = self.venv.reset()
        self._last_obs = np.array(obs, copy=True)
        return obs

    def step_async(self, actions: np.ndarray) -> None:
        if self._last_obs is None:
            raise RuntimeError("reset() the recording env before stepping it")
        if self.record_optimal and not self.full:
            self._pending_optimal = np.asarray(
                self.venv.env_method("optimal_action"), dtype=np.int64
            )
        self._pending_actions = np.array(actions, copy=True)
        self.venv.step_async(actions)

    def step_wait(self):
        obs, rewards, dones, infos = self.venv.step_wait()
        if not self.full:
            t = self.t
            next_true = np.array(obs, copy=True)
            for i in np.flatnonzero(dones):
                next_true[i] = infos[i]["terminal_observation"]  # the real s', not the reset state
            actions = self._pending_actions
            if "executed_action" in infos[0]:
                actions = np.stack([info["executed_action"] for info in infos])
            self.obs[:, t] = self._last_obs
            self.actions[:, t] = actions.reshape(self.actions[:, t].shape)
            self.rewards[:, t] = rewards
            self.next_obs[:, t] = next_true
            self.dones[:, t] = dones
            if self.record_optimal:
                self.optimal[:, t] = self._pending_optimal
            if "success" in infos[0]:
                if self.success is None:
                    self.success = np.zeros(self.rewards.shape, dtype=bool)
                self.success[:, t] = [bool(info["success"]) for info in infos]
        self.t += 1
        self._last_obs = np.array(obs, copy=True)
        return obs, rewards, dones, infos

    def arrays(self) -> dict[str, np.ndarray | None]:
        """The recorded streams; raises when fewer than ``steps`` transitions were seen."""
        if not self.full:
            raise RuntimeError(f"recorded only {self.t} of {self.steps} steps")
        return {
            "obs": self.obs,
            "actions": self.actions,
            "rewards": self.rewards,
            "next_obs": self.next_obs,
            "dones": self.dones,
            "optimal_actions": self.optimal,
            "success": self.success,
        }
