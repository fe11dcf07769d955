"""Studies over many runs: what accuracy costs in time, the training-set study (paper Fig. 5) and tuning.

One role per module (docs/studies.md):

* :mod:`~pipeline.study.settings`: the accuracy sweep's settings (:func:`accuracy_settings`);
* :mod:`~pipeline.study.accuracy`: ``stucco bench accuracy``, every setting on a (scene, seed) grid of the BOR
  tasks (:func:`accuracy_bench`);
* :mod:`~pipeline.study.pareto`: its summary, Pareto fronts of time against CE, FMI and GS, the knee, the figure;
* :mod:`~pipeline.study.training`: the training set SELECT1-4 collected, isolated, its ground truth and run
  ambiguity, tracked and scored per method;
* :mod:`~pipeline.study.figure5`: ``stucco study training``, the paper's Fig. 5 (:func:`training_study`);
* :mod:`~pipeline.study.tuning`: ``stucco study tune``, one parameter per method swept on the training set, the
  rule :func:`choose_setting`;
* :mod:`~pipeline.study.tables`: null-skipping statistics and atomic CSV files shared by the above.

Every random stream comes from the stages' own derivations (collect: ``[root, scene, seed]``; track:
``[root, run_key(run)]``), so a setting's result does not depend on the order or the process it runs in.
"""
from pipeline.study.accuracy import accuracy_bench
from pipeline.study.figure5 import fig5, training_study
from pipeline.study.pareto import knee, pareto_figure, pareto_front, summarise_settings, summary_markdown
from pipeline.study.settings import Setting, accuracy_settings
from pipeline.study.tables import write_csv
from pipeline.study.training import (AMBIGUITY_DISTANCE_M, MIN_REP_FORCE_N, TRAINING_SCENES, TRAINING_SEEDS,
                                     collect_training, run_ambiguity, training_scores)
from pipeline.study.tuning import choose_setting, dataclass_dict, tune

__all__ = ["Setting", "accuracy_settings", "pareto_front", "knee", "accuracy_bench", "summarise_settings",
           "summary_markdown", "pareto_figure", "run_ambiguity", "TRAINING_SCENES", "TRAINING_SEEDS",
           "AMBIGUITY_DISTANCE_M", "MIN_REP_FORCE_N", "collect_training", "training_scores", "training_study",
           "fig5", "choose_setting", "tune", "dataclass_dict", "write_csv"]
