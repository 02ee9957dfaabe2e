"""PyTorch datasets over a unified avdata dataset: frames, collaborative frames, sequences.

This is the only package of avdata that imports torch.
"""

from avdata.loaders.collate import collate_intermediate, collate_late, collate_list, collate_padded
from avdata.loaders.frame_dataset import FrameDataset
from avdata.loaders.options import Collaboration, FrameOptions, LabelFilter
from avdata.loaders.ray_dataset import ray_dataset
from avdata.loaders.sequence_dataset import SequenceDataset
from avdata.loaders.transforms import SceneTransforms

__all__ = ["Collaboration", "FrameDataset", "FrameOptions", "LabelFilter", "SceneTransforms", "SequenceDataset",
           "collate_intermediate", "collate_late", "collate_list", "collate_padded", "ray_dataset"]
