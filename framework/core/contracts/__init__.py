"""The contract of every plugin kind, one module each; the checks a test runs on every installed
plugin of a kind are in :mod:`framework.core.contracts.checks`.

| kind (entry-point group ``shape_from_caustics.<kind>``) | contract |
|---|---|
| ``operator`` | :class:`framework.core.contracts.operator.Operator` (base: operators/photon_operator.py, ``ImageOperator``) |
| ``data`` | :class:`framework.core.contracts.data_source.DataSource` |
| ``initial`` | :class:`framework.core.contracts.start.Start` |
| ``solver`` | :class:`framework.core.contracts.solver.SolverPlugin` |
| ``stopping`` | :class:`framework.core.contracts.stopping.StoppingRule` |
| ``regularizer``, ``post_step`` | :class:`regularizers.Regularizer`, :class:`regularizers.PostStepUpdate` |

Every member a contract names is there on every plugin of the kind (a base class gives the
defaults): optional behaviour is declared by a value (``conserves_energy``, ``has_prox``,
``needs_volume``), never found by probing for an attribute.
"""
