"""The Jacobian of a grey-box simulation error: shared columns dense, per-record columns one block each.

The residual of a grey-box problem (:func:`agents.twin.greybox.residual`) has
one row per sample of each record (record-major) and one column per free
parameter. A model (global) parameter moves every record, so its column is
dense; a record's rest level ``y0_k`` or input bias ``b_k`` moves only that
record, so its column is zero outside the record's samples. Stored dense, the
matrix has ``n_records * n_steps`` rows and ``2 n_records`` nuisance columns, so
its size grows with the square of the number of records; stored as its blocks it
takes ``(n_global + 2) * n_records * n_steps`` numbers, linear in the data.
:class:`RecordJacobian` is that storage as a :class:`scipy.sparse.linalg.LinearOperator`,
which ``scipy.optimize.least_squares`` accepts with ``tr_solver="lsmr"``.
"""

from __future__ import annotations

import numpy as np
from scipy.sparse.linalg import LinearOperator

__all__ = ["RecordJacobian"]


class RecordJacobian(LinearOperator):
    """Jacobian with dense shared columns and per-record columns, as a linear operator.

    Parameters
    ----------
    shared : ndarray of shape (n_shared, n_records, n_steps)
        Derivatives of the residual with respect to each shared (model) parameter.
    per_record : sequence of ndarray of shape (n_records, n_steps)
        For each kind of per-record parameter (e.g. the rest level, the input bias), the derivative
        of each record's residual with respect to its own parameter of that kind.
    columns : sequence of ndarray of int
        Position of each column in the operator: first ``columns[0]`` of shape (n_shared,) for the
        shared parameters, then for each kind of per-record parameter, ``(position, record)`` pairs as
        an array of shape (n_free, 2) (records whose parameter is fixed are left out).
    """

    def __init__(self, shared: np.ndarray, per_record, columns) -> None:
        n_records, n_steps = shared.shape[1:]
        self.shared = shared.reshape(shared.shape[0], n_records * n_steps)
        self.per_record = list(per_record)
        self.shared_columns = np.asarray(columns[0], dtype=int)
        self.record_columns = [np.asarray(c, dtype=int).reshape(-1, 2) for c in columns[1:]]
        n_columns = self.shared_columns.size + sum(c.shape[0] for c in self.record_columns)
        self.n_records = n_records
        super().__init__(dtype=float, shape=(n_records * n_steps, n_columns))

    def _matvec(self, v: np.ndarray) -> np.ndarray:
        v = np.ravel(v)
        out = v[self.shared_columns] @ self.shared
        for block, cols in zip(self.per_record, self.record_columns):
            coef = np.zeros(self.n_records)
            coef[cols[:, 1]] = v[cols[:, 0]]
            out += (block * coef[:, None]).ravel()
        return out

    def _rmatvec(self, w: np.ndarray) -> np.ndarray:
        w = np.ravel(w)
        out = np.empty(self.shape[1])
        out[self.shared_columns] = self.shared @ w
        rows = w.reshape(self.n_records, -1)
        for block, cols in zip(self.per_record, self.record_columns):
            out[cols[:, 0]] = np.einsum("kn,kn->k", block, rows)[cols[:, 1]]
        return out

    def toarray(self) -> np.ndarray:
        """The dense matrix, shape ``self.shape``, column-major (each column contiguous)."""
        out = np.zeros(self.shape, order="F")
        out[:, self.shared_columns] = self.shared.T
        n_steps = self.shape[0] // self.n_records
        for block, cols in zip(self.per_record, self.record_columns):
            for position, record in cols:
                out[record * n_steps : (record + 1) * n_steps, position] = block[record]
        return out
