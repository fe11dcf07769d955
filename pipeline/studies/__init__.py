"""Benchmarks and studies over many runs: what speed and accuracy cost, where grasps are lost, the training-set
study (paper Fig. 5) and tuning.

One role per module (docs/studies.md):

* :mod:`~pipeline.studies.accuracy_settings`: the accuracy sweep's settings (:func:`accuracy_settings`);
* :mod:`~pipeline.studies.accuracy`: ``stucco bench accuracy``, every setting on a (scene, seed) grid of the BOR
  tasks (:func:`accuracy_bench`);
* :mod:`~pipeline.studies.pareto`: its summary, Pareto fronts of time against CE, FMI and GS, the knee, the figure;
* :mod:`~pipeline.studies.training`: the training set SELECT1-4 collected, isolated, its ground truth and run
  ambiguity, tracked and scored per method;
* :mod:`~pipeline.studies.training_figure`: ``stucco study training``, the paper's Fig. 5 (:func:`training_study`);
* :mod:`~pipeline.studies.tuning`: ``stucco study tune``, one parameter per method swept on the training set, the
  rule :func:`choose_setting`;
* :mod:`~pipeline.studies.trackers`: ``stucco bench track``, the trackers' speed and accuracy on the authors' streams
  (:mod:`~pipeline.studies.anchors` reads those streams);
* :mod:`~pipeline.studies.sim_effects`: ``stucco sim-bench``, what each simulation effect costs;
* :mod:`~pipeline.studies.probe_budget`: ``stucco bench probe``, the active protocol's grasp success against its
  probe budget;
* :mod:`~pipeline.studies.pushes`: ``stucco bench pushes``, the pushing models against the simulator, push by push;
* :mod:`~pipeline.studies.retrieval_ladder` (and its report): ``stucco bench retrieval``, grasp success from the
  true pose down to the tracker's points;
* :mod:`~pipeline.studies.scale`, :mod:`~pipeline.studies.scale_contacts`: ``stucco bench scale``;
* :mod:`~pipeline.studies.tables`: null-skipping statistics and atomic CSV files shared by the above.

Every random stream comes from the stages' own derivations (collect: ``[root, scene, seed]``; track:
``[root, run_key(run)]``), so a setting's result does not depend on the order or the process it runs in.
"""
