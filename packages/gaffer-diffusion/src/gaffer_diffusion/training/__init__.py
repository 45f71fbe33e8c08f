"""Training of the Neural Gaffer UNet on gaffer-data renders and converted authors' splits (extra
`gaffer-diffusion[train]`).

Reads gaffer-data renders through gaffer-data's public reader (`gaffer_data.dataset`), as `evaluation` and
`demo` do; import-linter forbids its internals. Entry points: `load_config` + `train`, or the
command line `gaffer-diffusion train --config CONFIG [--resume]`.
"""

from gaffer_diffusion.training.batch import TrainItem
from gaffer_diffusion.training.config import (
    CheckpointConfig,
    DataConfig,
    LoggingConfig,
    ModelSource,
    OptimConfig,
    TrainConfig,
    TrainLoopConfig,
    ValidationConfig,
    load_config,
)
from gaffer_diffusion.training.dataset import (
    KeySampler,
    RelightTrainDataset,
    TrainBatch,
    batch_lighting,
    collate_items,
    encode_batch_lighting,
    split_object_ids,
)
from gaffer_diffusion.training.ema import EMAModel
from gaffer_diffusion.training.errors import DataError, ResumeError, TrainingDivergedError
from gaffer_diffusion.training.loop import (
    TrainResult,
    build_training_model,
    cfg_dropout_masks,
    load_checkpoint_model,
    train,
)
from gaffer_diffusion.training.objects import check_lighting_compat, dataset_object_ids
from gaffer_diffusion.training.validation import ValidationResult

__all__ = [
    "CheckpointConfig",
    "DataConfig",
    "DataError",
    "EMAModel",
    "KeySampler",
    "LoggingConfig",
    "ModelSource",
    "OptimConfig",
    "RelightTrainDataset",
    "ResumeError",
    "TrainBatch",
    "TrainConfig",
    "TrainItem",
    "TrainLoopConfig",
    "TrainResult",
    "TrainingDivergedError",
    "ValidationConfig",
    "ValidationResult",
    "batch_lighting",
    "build_training_model",
    "cfg_dropout_masks",
    "check_lighting_compat",
    "collate_items",
    "dataset_object_ids",
    "encode_batch_lighting",
    "load_checkpoint_model",
    "load_config",
    "split_object_ids",
    "train",
]
