"""Motion sequences and motion files (AMASS npz, CMU ASF/AMC, BVH), retargeted to SMPL's tree."""

from .sequence import Motion as Motion
