"""lhf_hf: learning history filtering (LHF) for in-context RL on the Hugging Face stack.

Importing the package is cheap: subpackages (``lhf_hf.envs``, ...) are imported on use.
"""

__version__ = "0.1.0"
