"""Activity recognition from one wrist IMU (Huang ch. 7): an MLP over 6 s windows plus a
linear-chain CRF.

Pipeline (Fig. 7.4, §7.3-7.4):

1. Readings. `watch_readings(motion, body, rng)`: the "left_forearm" sensor of the sip6 set
   (the watch, on the forearm near the wrist) simulated at the motion's own rate with an
   IMU error model (`jaxmocap.sensors.errors`, default `IMUErrorModel.xsens()`), then
   brought to 10 fps (the thesis downsamples "to rule out high-frequency details"): the
   reading at t_k = k / 10 s is the mean of the native samples in [t_k - 0.05, t_k + 0.05)
   (a box low-pass, so no aliasing of the 60-120 Hz signal; dropped samples are left out
   of the mean, a bin with none holds the previous bin's value). Each frame is
   (a (3), r (3)): specific force (gravity included, what a watch measures, m/s²) and
   angular rate (rad/s), both in the sensor frame.
2. Features. `window_features`: x_t = vec(a_{t-M+1}, ..., a_t, r_{t-M+1}, ..., r_t) with
   M = 60 frames (6 s at 10 fps, the current frame included): 360 values, all
   accelerations first, then all rates, each frame's 3 axes together. Frames before the
   start of a sequence repeat its first frame (a watch that was held still before the
   recording; the alternative, zeros, is far out of distribution for an accelerometer).
   Each of the 6 channels is standardised by mean and standard deviation of the training
   readings (`Standardiser`, stored with the model).
3. Per-frame class probabilities p_t = softmax(MLP(x_t)), MLP 360 → 1024 → 512 → 60 → C,
   each hidden layer followed by ReLU and Dropout 0.5 (Fig. 7.6).
4. Linear-chain CRF (eq. 7.2): the label sequence S maximises

       score(S) = Σ_t λ log p_{S_t}(t) + Σ_t A_{S_t, S_{t+1}}

   i.e. eq. 7.2 with the unary p replaced by λ log p (a log-linear CRF whose unary is the
   MLP's log-probability) and λT by the transition scores A (C, C). `viterbi` finds the
   maximiser (max-product recursion + backtracking, `lax.scan`), `crf_log_likelihood`
   computes log P(S) = score(S) - log Z with the exact forward algorithm (log-sum-exp
   recursion). A starts as the log transition frequencies of the training labels (the
   thesis computes T from training sequences, Fig. 7.5); A and λ are then learned by
   maximising the CRF log-likelihood with the MLP fixed (`train_crf`).

Labelling rule (`activity_labels` = `labels_from_signals(label_signals(...))`, thresholds
in `LabelRule`). Labels come from the true motion, frame by frame, so that classes occur
across subjects (a clip's own activity name is subject-specific in the CMU data: only
subject 2 punches, only subject 5 dances). With v the pelvis horizontal speed, everything
averaged over a centred 1 s window:

    jump        the lower foot is > 0.15 m above the ground (the lowest foot height
                within ±1 s), i.e. both feet clearly off it; padded by 0.25 s on each
                side (take-off and landing)
    run         v > 1.8 m/s and a flight phase: in > 25 % of the window neither foot is
                planted (each foot's ankle and toe joints both move faster than 1 m/s)
    turn_left   the pelvis heading changes by > 60° within the window, counter-clockwise
    turn_right  seen from above (y up) for turn_left, clockwise for turn_right
    bend        the trunk (pelvis → neck) tilts > 35° from vertical, or the pelvis is
                below 0.8 x its standing height above the soles (bend over, crouch, squat)
    walk        v > 0.5 m/s
    arms_up     a wrist above the head joint (window mean): reach up, arms held high
    arms        a wrist moves faster than 0.8 m/s relative to the pelvis (punch, wash,
                dribble, swordplay while standing)
    still       none of the above

The first matching line wins (jump before run before turn ...). `LabelRule.watch_arm = 1`
makes arms_up and arms look at the watch's (left) wrist alone. Then label flicker is
removed: every segment shorter than 0.5 s takes the label of its longer neighbour,
shortest first. Heights use the body's rest pose: a foot joint's height is its y minus its
rest height above the soles, so a flat foot reads 0.

Features beyond the thesis: `summary_features` (statistics of 1, 3 and 6 s windows of the
raw readings: forearm orientation from the mean specific force, shaking, angular rate, the
rate about the vertical) are what `experiments/har.py` feeds the MLP by default; on five
subjects' worth of motion they are less to learn than the 360 raw values.

Randomness: every function that draws takes a `numpy.random.Generator` or a JAX key.

Files, one concern each (every public name is also importable from this package):
`labels` (the labelling rule), `readings` (the simulated watch), `features` (windows,
summary statistics, standardisation), `mlp` (the per-frame classifier and its training),
`crf` (the chain: score, log Z, Viterbi, training), `scores` (confusion and curves),
`classifier` (the trained recogniser and its file); `_motion` poses the true motion for
`labels` and `readings`.
"""

from .labels import CLASSES as CLASSES
from .labels import LabelRule as LabelRule
from .labels import activity_labels as activity_labels
from .labels import label_signals as label_signals
from .labels import labels_from_signals as labels_from_signals
from .labels import SIGNALS as SIGNALS
from .readings import WATCH_RATE as WATCH_RATE
from .readings import WATCH_SENSOR as WATCH_SENSOR
from .readings import NUM_CHANNELS as NUM_CHANNELS
from .readings import watch_readings as watch_readings
from .readings import resample_labels as resample_labels
from .features import WINDOW as WINDOW
from .features import summary_features as summary_features
from .features import summary_feature_names as summary_feature_names
from .features import SUMMARY_WINDOWS as SUMMARY_WINDOWS
from .features import window_features as window_features
from .features import Standardiser as Standardiser
from .features import fit_standardiser as fit_standardiser
from .mlp import ActivityMLP as ActivityMLP
from .mlp import train_mlp as train_mlp
from .mlp import mlp_log_probs as mlp_log_probs
from .mlp import class_weights as class_weights
from .crf import ActivityCRF as ActivityCRF
from .crf import init_crf as init_crf
from .crf import transition_counts as transition_counts
from .crf import crf_score as crf_score
from .crf import decode as decode
from .crf import crf_log_partition as crf_log_partition
from .crf import crf_log_likelihood as crf_log_likelihood
from .crf import viterbi as viterbi
from .crf import train_crf as train_crf
from .scores import TrainingCurve as TrainingCurve
from .scores import confusion_matrix as confusion_matrix
from .scores import classification_scores as classification_scores
from .classifier import ActivityClassifier as ActivityClassifier
from .classifier import save_classifier as save_classifier
from .classifier import load_classifier as load_classifier
from .classifier import FORMAT as FORMAT
from .classifier import FORMAT_VERSION as FORMAT_VERSION
from .classifier import ActivityModelError as ActivityModelError

__all__ = [
    "CLASSES",
    "WATCH_RATE",
    "WINDOW",
    "WATCH_SENSOR",
    "LabelRule",
    "activity_labels",
    "label_signals",
    "labels_from_signals",
    "SIGNALS",
    "summary_features",
    "summary_feature_names",
    "SUMMARY_WINDOWS",
    "watch_readings",
    "resample_labels",
    "window_features",
    "Standardiser",
    "fit_standardiser",
    "ActivityMLP",
    "ActivityCRF",
    "ActivityClassifier",
    "init_crf",
    "transition_counts",
    "crf_score",
    "decode",
    "crf_log_partition",
    "crf_log_likelihood",
    "viterbi",
    "TrainingCurve",
    "train_mlp",
    "train_crf",
    "mlp_log_probs",
    "class_weights",
    "confusion_matrix",
    "classification_scores",
    "save_classifier",
    "load_classifier",
    "ActivityModelError",
]
