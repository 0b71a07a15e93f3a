"""Column names, the dataset's file names and format versions (docs/design.md 4); the other
artifacts name their files beside their code."""

from typing import Literal, get_args

# ---- frames (one row per transition), LeRobot v3.0 names plus the lhf extension
OBS = "observation.state"
ACTION = "action"
REWARD = "next.reward"
DONE = "next.done"
NEXT_OBS = "next.observation.state"
SUCCESS = "next.success"  # envs that report info["success"] (Meta-World; Key-to-Door via SB3)
OPTIMAL_ACTION = "action.optimal"  # gridworlds: the oracle's action (DPT labels)
INDEX = "index"
FRAME_INDEX = "frame_index"  # step within the episode
EPISODE_INDEX = "episode_index"
TASK_INDEX = "task_index"  # LeRobot's dense index into meta/tasks.parquet (0..total_tasks-1)
TASK_ID = "task_id"  # the env's own task number (what `--tasks` names); lhf's extra column
HISTORY_INDEX = "history_index"
TIMESTAMP = "timestamp"

# ---- episodes table
EPISODE_IN_HISTORY = "episode_in_history"
LENGTH = "length"
EPISODE_RETURN = "episode_return"
EPISODE_SUCCESS = "success"
FROM_INDEX = "dataset_from_index"
TO_INDEX = "dataset_to_index"
EPISODE_TASKS = "tasks"  # LeRobot v3.0: the task strings of the episode
DATA_CHUNK = "data/chunk_index"  # LeRobot v3.0: where the episode's frames are
DATA_FILE = "data/file_index"
META_CHUNK = "meta/episodes/chunk_index"  # LeRobot v3.0: where the episode's own row is
META_FILE = "meta/episodes/file_index"
EPISODE_STATS = "stats"  # LeRobot v3.0: per-episode stats columns ``stats/{feature}/{stat}``

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
DATA_FILES_SIZE_IN_MB = 100  # LeRobot's cap on a data file's size (lhf writes one file per task)
VIDEO_FILES_SIZE_IN_MB = 200  # LeRobot's default; lhf writes no video
DATA_PATH = "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"
INFO_PATH = "meta/info.json"
STATS_PATH = "meta/stats.json"
TASKS_PATH = "meta/tasks.parquet"
EPISODES_PATH = "meta/episodes/chunk-000/file-000.parquet"
HISTORIES_PATH = "meta/histories/chunk-000/file-000.parquet"
PARTS_DIR = "meta/.parts"  # per-task episode/history rows, assembled at finalize
CONFIG_PATH = "meta/lhf_config.json"  # written first: identifies an unfinished collection
LHF_INFO_PATH = "meta/lhf_info.json"  # the lhf extension's metadata (info.json stays LeRobot's own)
#: Version of lhf's layout on top of LeRobot v3.0: 2 = dense task_index, the env's task in task_id,
#: the lhf metadata in LHF_INFO_PATH.  Datasets of layout 1 are upgraded by ``lhf upgrade``.
LAYOUT_VERSION = 2
CURVE_PATH = "meta/learning_curve.png"
CARD_PATH = "README.md"

#: The ICRL objectives (backbones of the paper), named once for configs, models and experiments.
Objective = Literal["ad", "dpt", "dicp"]
OBJECTIVES: tuple[str, ...] = get_args(Objective)
