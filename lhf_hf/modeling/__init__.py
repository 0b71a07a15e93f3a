"""ICRL models (AD, DPT, DICP) on ``transformers.LlamaModel``; registered with AutoConfig/AutoModel."""

from lhf_hf.configs.model import PRESETS

from .configuration_icrl import ICRLConfig, icrl_config
from .loading import load_model
from .modeling_icrl import ICRLModel, ICRLOutput, ICRLPreTrainedModel

__all__ = [
    "PRESETS",
    "ICRLConfig",
    "ICRLModel",
    "ICRLOutput",
    "ICRLPreTrainedModel",
    "icrl_config",
    "load_model",
]
