"""The contract of every plugin kind, one module each; the checks a test runs on every installed
plugin of a kind are in :mod:`framework.core.contracts.checks`.

| kind (entry-point group ``shape_from_caustics.<kind>``) | contract |
|---|---|
| ``operator`` | :class:`operators.image_operator.ImageOperator` |
| ``data`` | :class:`framework.core.contracts.data_source.DataSource` (several shots: ``ShotStack``) |
| ``initial`` | :class:`framework.core.contracts.start.Start` |
| ``solver`` | :class:`framework.core.solver_loop.IterativeSolver` with ``from_config`` (:mod:`framework.core.contracts.solver`) |
| ``stopping`` | :class:`framework.core.contracts.stopping.StoppingRule` |
| ``regularizer``, ``post_step`` | :class:`regularizers.Regularizer`, :class:`regularizers.PostStepUpdate` |
| ``step_size``, ``preconditioner`` | :class:`framework.optimization.step_size.StepSizePolicy`, :class:`framework.optimization.preconditioner.GradientPreconditioner` |

One style for every kind: a plugin derives from its kind's abstract base class, implements the
base's abstract methods (what only it can give) and inherits a default for everything else.
Optional behaviour is declared by a value (``conserves_energy``, ``has_prox``, ``needs_volume``),
never found by probing for an attribute; what the framework reads of every plugin class
(``from_config``, ``length_keys``, ``example_settings``) is declared once on
:class:`operators.plugin.Plugin`, which every base derives from. The operator's base lives in
operators/ (which knows nothing of the framework).
:func:`framework.core.contracts.checks.check_base` refuses a plugin that does not derive from its
kind's base.
"""
