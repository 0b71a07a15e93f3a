"""Column names, file names and format versions: spelled out here and nowhere else (docs/design.md 4)."""

from typing import Literal, get_args

# ---- frames (one row per transition), LeRobot v3.0 names plus the lhf extension
OBS = "observation.state"
ACTION = "action"
REWARD = "next.reward"
DONE = "next.done"
NEXT_OBS = "next.observation.state"
SUCCESS = "next.success"  # envs that report info["success"] (Meta-World, Key-to-Door)
OPTIMAL_ACTION = "action.optimal"  # gridworlds: the oracle's action (DPT labels)
INDEX = "index"
FRAME_INDEX = "frame_index"  # step within the episode
EPISODE_INDEX = "episode_index"
TASK_INDEX = "task_index"
HISTORY_INDEX = "history_index"
TIMESTAMP = "timestamp"

# ---- episodes table
EPISODE_IN_HISTORY = "episode_in_history"
LENGTH = "length"
EPISODE_RETURN = "episode_return"
EPISODE_SUCCESS = "success"
FROM_INDEX = "dataset_from_index"
TO_INDEX = "dataset_to_index"

# ---- histories table
HISTORY_IN_TASK = "history_in_task"
LEARNER = "learner"  # ppo / sac / random
LEARNER_INDEX = "learner_index"  # which learner of the task made it (paper protocol: one per task)
SEED = "seed"
RETURNS = "returns"
NUM_EPISODES = "num_episodes"

# ---- tasks table
TASK = "task"
SPLIT = "split"
TASK_PARAMS = "task_parameters"  # JSON string of the env's task parameters

# ---- layout
CODEBASE_VERSION = "v3.0"
FPS = 1  # one frame per environment step; timestamp = frame_index
CHUNKS_SIZE = 1000  # files per chunk directory
DATA_PATH = "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"
INFO_PATH = "meta/info.json"
STATS_PATH = "meta/stats.json"
TASKS_PATH = "meta/tasks.parquet"
EPISODES_PATH = "meta/episodes/chunk-000/file-000.parquet"
HISTORIES_PATH = "meta/histories/chunk-000/file-000.parquet"
PARTS_DIR = "meta/.parts"  # per-task episode/history rows, assembled at finalize
CONFIG_PATH = "meta/lhf_config.json"  # written first: identifies an unfinished collection
CURVE_PATH = "meta/learning_curve.png"
CARD_PATH = "README.md"

#: The ICRL objectives (backbones of the paper), named once for configs, models and experiments.
Objective = Literal["ad", "dpt", "dicp"]
OBJECTIVES: tuple[str, ...] = get_args(Objective)
