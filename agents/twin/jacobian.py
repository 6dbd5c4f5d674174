"""The Jacobian of a grey-box simulation error: dense for small problems, compressed record by record for large ones.

The residual of a grey-box problem (:func:`agents.twin.least_squares.residual`) has
one row per sample of each record (record-major) and one column per free
parameter. A model (global) parameter moves every record, so its column is
dense; a record's rest level ``y0_k`` or input bias ``b_k`` moves only that
record, so its column is zero outside the record's samples. Stored dense, the
matrix has ``n_records * n_steps`` rows and ``2 n_records`` nuisance columns, so
its size grows with the square of the number of records (:func:`dense_jacobian`
builds it for small problems).

For large problems only the normal equations matter to the trust-region
iteration (:func:`agents.twin.trust_region.trf`). Record ``k``'s block ``J_k``
(its samples, by its own ``p`` columns: the free global parameters and its own
nuisances) has the thin QR factorisation ``J_k = Q_k R_k``; then

.. math:: J^T J = \\sum_k R_k^T R_k, \\qquad J^T f = \\sum_k R_k^T (Q_k^T f_k),

so the sparse matrix of the stacked ``R_k`` (``p`` rows per record, placed in
their columns) with the right-hand side of the stacked ``Q_k^T f_k``
(:class:`RecordQR`) has the same normal equations, gradient and linear
least-squares steps as ``(J, f)``, in ``p^2`` numbers per record instead of
``p n_steps``. The blocks are factorised a few records at a time, so the full
Jacobian never exists.
"""

from __future__ import annotations

import numpy as np
from scipy import sparse

__all__ = ["RecordQR", "dense_jacobian"]


def dense_jacobian(shared: np.ndarray, per_record, columns) -> np.ndarray:
    """The Jacobian as a dense matrix, column-major (each column contiguous).

    Parameters
    ----------
    shared : ndarray of shape (n_shared, n_records, n_steps)
        Derivatives of the residual with respect to each shared (model) parameter.
    per_record : sequence of ndarray of shape (n_records, n_steps)
        For each kind of per-record parameter (e.g. the rest level, the input bias), the derivative
        of each record's residual with respect to its own parameter of that kind.
    columns : sequence of ndarray of int
        Position of each column in the matrix: first ``columns[0]`` of shape (n_shared,) for the
        shared parameters, then for each kind of per-record parameter, ``(position, record)`` pairs as
        an array of shape (n_free, 2) (records whose parameter is fixed are left out).

    Returns
    -------
    ndarray of shape (n_records * n_steps, n_columns)
        Units of the residual per unit of each parameter.
    """
    n_shared, n_records, n_steps = shared.shape
    record_columns = [np.asarray(c, dtype=int).reshape(-1, 2) for c in columns[1:]]
    out = np.zeros((n_records * n_steps, n_shared + sum(c.shape[0] for c in record_columns)), order="F")
    out[:, np.asarray(columns[0], dtype=int)] = shared.reshape(n_shared, n_records * n_steps).T
    for block, cols in zip(per_record, record_columns):
        for position, record in cols:
            out[record * n_steps : (record + 1) * n_steps, position] = block[record]
    return out


class RecordQR:
    """The Jacobian compressed to one triangular block per record, filled a few records at a time.

    Parameters
    ----------
    n_records : int
    n_columns : int
        Columns ``p`` of a record's block: the free shared parameters, then one per kind of
        per-record parameter.

    Attributes
    ----------
    r : ndarray of shape (n_records, n_columns, n_columns)
        ``R_k`` of each record's block ``J_k = Q_k R_k``.
    qf : ndarray of shape (n_records, n_columns)
        ``Q_k^T f_k`` of each record's residual.
    """

    def __init__(self, n_records: int, n_columns: int) -> None:
        self.r = np.zeros((n_records, n_columns, n_columns))
        self.qf = np.zeros((n_records, n_columns))

    def add(self, records: slice, blocks: np.ndarray, residual: np.ndarray) -> None:
        """Factorise the blocks of ``records``.

        Parameters
        ----------
        records : slice
            The records' positions.
        blocks : ndarray of shape (n_columns, n, n_steps)
            Each column of the blocks of the ``n`` records.
        residual : ndarray of shape (n, n_steps)
            Their residual ``f``.
        """
        q, r = np.linalg.qr(np.moveaxis(blocks, 0, -1))  # one thin QR per record: (n, n_steps, p), (n, p, p)
        self.r[records] = r
        self.qf[records] = np.einsum("kti,kt->ki", q, residual)

    def system(self, positions: np.ndarray, n_free: int) -> tuple[sparse.csr_array, np.ndarray]:
        """The compressed least-squares system ``(J~, f~)``: ``J~^T J~ = J^T J``, ``J~^T f~ = J^T f``.

        Parameters
        ----------
        positions : ndarray of int, shape (n_records, n_columns)
            Position of each column of each record's block among the free parameters; -1 for a
            parameter that is fixed (its column is zero).
        n_free : int
            Free parameters in all.

        Returns
        -------
        jacobian : scipy.sparse.csr_array of shape (n_records * n_columns, n_free)
        rhs : ndarray of shape (n_records * n_columns,)
        """
        k, p = positions.shape
        rows = np.broadcast_to(np.arange(k * p).reshape(k, p, 1), (k, p, p))
        cols = np.broadcast_to(positions[:, None, :], (k, p, p))
        keep = cols >= 0
        matrix = sparse.csr_array((self.r[keep], (rows[keep], cols[keep])), shape=(k * p, n_free))
        return matrix, self.qf.ravel()
