"""Outputs of an identification: parameters YAML, PNG figures (Figs. 6-8 style) and ``report.md``.

:func:`write_report` writes into one folder::

    params.yaml        fitted MembraneParameters (loadable by MembraneParameters.from_yaml)
    report.md          parameter table (Table II style, with 95 % CIs), metrics (Tables III-IV),
                       correlations, warnings, timings
    result.json        the same content, machine readable (IdentificationResult.to_dict())
    static.png         Fig. 6: rest displacement vs voltage (and vs mass), data and model
    step.png           Fig. 8 left: step responses, data and model, and the error
    frequency.png      Fig. 8 right: RMS displacement vs frequency, data and model (with the model's
                       confidence band and the peak's interval when the identification computed them)
    sine_series.png    sampled sine records vs model (when the data include them)

Every output is a view of the result objects (:class:`~dea_ros.identify.result.IdentificationResult`
and its :class:`~dea_ros.identify.evaluation.Evaluation`): :mod:`.parameters_file` (params.yaml),
:mod:`.markdown` (report.md, one function per section), :mod:`.figures` (the PNG figures),
:mod:`.folder` (the whole folder).
"""
from .figures import plot_frequency, plot_sine_series, plot_static, plot_steps
from .folder import write_report
from .markdown import report_markdown
from .parameters_file import write_parameters

__all__ = ["write_report", "write_parameters", "plot_static", "plot_steps", "plot_frequency",
           "plot_sine_series", "report_markdown"]
