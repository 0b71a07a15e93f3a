"""ICRL models (AD, DPT, DICP) on ``transformers.LlamaModel``; registered with AutoConfig/AutoModel.

Importing this package registers ``lhf_icrl`` with transformers' Auto classes, so that
``AutoModel.from_pretrained`` builds lhf_hf's own classes (also with ``trust_remote_code=True``:
transformers prefers a registered class to a checkpoint's copy of the code).  Without lhf_hf, a
checkpoint loads from the copy of this code saved beside its weights (``remote_code``).
"""

from transformers import AutoConfig, AutoModel

from lhf_hf.configs.model import PRESETS

from .configuration_icrl import ICRLConfig, icrl_config
from .loading import load_model
from .modeling_icrl import ICRLModel, ICRLOutput, ICRLPreTrainedModel
from .remote_code import AUTO_MAP, MODEL_CODE_FILES, save_model_code

# Here, not in modeling_icrl.py: that file is also the checkpoint's copy of the code, which
# transformers registers itself when it loads it as remote code.
AutoConfig.register(ICRLConfig.model_type, ICRLConfig, exist_ok=True)
AutoModel.register(ICRLConfig, ICRLModel, exist_ok=True)

__all__ = [
    "AUTO_MAP",
    "MODEL_CODE_FILES",
    "PRESETS",
    "ICRLConfig",
    "ICRLModel",
    "ICRLOutput",
    "ICRLPreTrainedModel",
    "icrl_config",
    "load_model",
    "save_model_code",
]
