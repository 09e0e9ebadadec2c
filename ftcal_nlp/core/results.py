"""One results protocol for every estimate of the package (after statsmodels' results classes).

Every fitted stage (hanging, standing, the diagnosis' fits, the whole
:class:`~ftcal_nlp.calibration_run.CalibrationRun`) exposes

* ``params``: labelled estimates (``pandas.Series``, SI units: N, N*m, m, rad);
* ``bse``: their standard errors, ``inf`` where the data do not determine a
  parameter (it is listed by ``undetermined_params``), ``NaN`` where the stage does not
  estimate it (a value kept from an earlier stage);
* ``cov_params()``: the labelled covariance (``pandas.DataFrame``); rows and
  columns of undetermined parameters are NaN with ``inf`` on the diagonal;
* ``conf_int(alpha=0.05)``: normal-theory intervals ``params -+ z_{1-alpha/2} bse``;
* ``summary()``: a :class:`Summary` that renders as text, HTML and LaTeX.

Standard errors of anything derived from the parameters follow by the delta
method, :meth:`ResultsMixin.propagate` (a Jacobian in, a covariance out), which
treats undetermined parameters honestly: a derived quantity that depends on one
gets an infinite standard error, one that does not is unaffected.

One value-and-error style everywhere: :func:`fmt_pm` (``1.234 ± 0.012``, the
value rounded to two significant digits of its standard error).
"""

from __future__ import annotations

import html
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np
import pandas as pd
from scipy.stats import norm

__all__ = ["fmt_pm", "bic", "Summary", "ResultsMixin", "StackedResults", "block_diag_cov", "cov_frame"]

PM = "±"


def fmt_pm(value: float, se: float | None, *, scale: float = 1.0) -> str:
    """``value ± se`` (both times ``scale``) with as many decimals as two significant digits of se warrant.

    ``se`` None or NaN: the value was not estimated here (``"1.23 (fixed)"``); ``inf``:
    not determined by the data (``"1.23 ± inf"``); a non-finite value gives ``"n/a"``.
    """
    if value is None or not np.isfinite(value):
        return "n/a"
    v = float(value) * scale
    if se is None or np.isnan(se):
        return f"{v:.4g} (fixed)"
    s = float(se) * scale
    if not np.isfinite(s):
        return f"{v:.4g} {PM} inf"
    if s <= 0:
        return f"{v:.4g} {PM} 0"
    dec = max(0, int(-np.floor(np.log10(s))) + 1)
    return f"{v:.{dec}f} {PM} {s:.{dec}f}"


def bic(rss: float, n: int, dof: int) -> float:
    """Bayesian information criterion of a least-squares fit, ``n ln(RSS/n) + dof ln n`` (report Sec. IV-2)."""
    return float(n * np.log(rss / n) + dof * np.log(n))


def cov_frame(cov: np.ndarray, names: Sequence[str], bse: np.ndarray | None = None) -> pd.DataFrame:
    """A labelled covariance; where ``bse`` is inf the row and column are NaN and the diagonal inf."""
    c = np.array(cov, dtype=float, copy=True)
    if bse is not None:
        bad = ~np.isfinite(np.asarray(bse, float))
        c[bad, :] = np.nan
        c[:, bad] = np.nan
        c[bad, bad] = np.where(np.isinf(bse[bad]), np.inf, np.nan)
    return pd.DataFrame(c, index=list(names), columns=list(names))


def block_diag_cov(frames: Sequence[pd.DataFrame]) -> pd.DataFrame:
    """Block-diagonal covariance of independent parameter groups (zeros between groups)."""
    names = [n for f in frames for n in f.index]
    out = np.zeros((len(names), len(names)))
    i = 0
    for f in frames:
        n = len(f)
        out[i : i + n, i : i + n] = f.to_numpy()
        i += n
    return pd.DataFrame(out, index=names, columns=names)


@dataclass
class Summary:
    """A result's summary: a title, key facts, labelled tables and notes.

    Tables are DataFrames whose index holds row labels (with units) and whose
    cells are already formatted strings or numbers. Rendered by :meth:`as_text`,
    :meth:`as_html` and :meth:`as_latex`; ``str(summary)`` is the text.
    """

    title: str
    facts: list[tuple[str, str]] = field(default_factory=list)
    tables: list[tuple[str, pd.DataFrame]] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)

    def as_text(self) -> str:
        lines = [self.title, "=" * len(self.title)]
        if self.facts:
            w = max(len(k) for k, _ in self.facts)
            lines += [f"{k:<{w}} : {v}" for k, v in self.facts]
        for caption, df in self.tables:
            lines += ["", caption, "-" * len(caption), _text_table(df)]
        if self.notes:
            lines.append("")
            lines += [f"* {n}" for n in self.notes]
        return "\n".join(lines)

    def as_html(self) -> str:
        out = [f"<h3>{html.escape(self.title)}</h3>"]
        if self.facts:
            out.append("<table class='facts'>" + "".join(
                f"<tr><th>{html.escape(k)}</th><td>{html.escape(v)}</td></tr>" for k, v in self.facts) + "</table>")
        for caption, df in self.tables:
            out.append(f"<h4>{html.escape(caption)}</h4>" + _html_table(df))
        if self.notes:
            out.append("<ul>" + "".join(f"<li>{html.escape(n)}</li>" for n in self.notes) + "</ul>")
        return "\n".join(out)

    def as_latex(self) -> str:
        out = [f"\\subsection*{{{latex_escape(self.title)}}}"]
        if self.facts:
            out += ["\\begin{tabular}{ll}"] + [f"{latex_escape(k)} & {latex_escape(v)} \\\\" for k, v in self.facts] + ["\\end{tabular}"]
        for caption, df in self.tables:
            out.append(latex_table(df, caption))
        if self.notes:
            out += ["\\begin{itemize}"] + [f"\\item {latex_escape(n)}" for n in self.notes] + ["\\end{itemize}"]
        return "\n".join(out)

    def __str__(self) -> str:
        return self.as_text()

    def _repr_html_(self) -> str:
        return self.as_html()


def _cell(v) -> str:
    if isinstance(v, (float, np.floating)):
        return f"{v:.4g}" if np.isfinite(v) else "n/a"
    return str(v)


def _index_name(df: pd.DataFrame) -> str:
    return "" if df.index.name is None else str(df.index.name)


def _text_table(df: pd.DataFrame) -> str:
    head = [_index_name(df)] + [str(c) for c in df.columns]
    rows = [[str(i)] + [_cell(v) for v in r] for i, r in zip(df.index, df.itertuples(index=False))]
    w = [max(len(x) for x in col) for col in zip(head, *rows)]
    fmt = lambda r: "  ".join([r[0].ljust(w[0])] + [c.rjust(wi) for c, wi in zip(r[1:], w[1:])])  # noqa: E731
    return "\n".join([fmt(head), "  ".join("-" * x for x in w)] + [fmt(r) for r in rows])


def _html_table(df: pd.DataFrame) -> str:
    head = "".join(f"<th>{html.escape(str(c))}</th>" for c in [_index_name(df), *df.columns])
    body = "".join(
        "<tr><th>" + html.escape(str(i)) + "</th>" + "".join(f"<td>{html.escape(_cell(v))}</td>" for v in r) + "</tr>"
        for i, r in zip(df.index, df.itertuples(index=False)))
    return f"<table class='tbl'><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


_LATEX = {"\\": "\\textbackslash{}", "_": "\\_", "%": "\\%", "&": "\\&", "#": "\\#", "^": "\\^{}", "{": "\\{",
          "}": "\\}", "$": "\\$", "~": "\\~{}", PM: "$\\pm$", "²": "$^2$"}


def latex_escape(s: str) -> str:
    """Text -> LaTeX, one character at a time (so no replacement is escaped again): specials
    escaped, ``±`` as ``$\\pm$``, the old ``+-`` likewise."""
    return "".join(_LATEX.get(ch, ch) for ch in str(s)).replace("+-", "$\\pm$")


def latex_table(df: pd.DataFrame, caption: str = "", label: str = "") -> str:
    """A ``table`` float with the index as the first column."""
    cols = [_index_name(df)] + [str(c) for c in df.columns]
    out = ["\\begin{table}[t]", "\\centering"]
    if caption:
        out.append(f"\\caption{{{latex_escape(caption)}}}")
    if label:
        out.append(f"\\label{{{label}}}")
    out += ["\\begin{tabular}{l" + "r" * (len(cols) - 1) + "}", "\\hline", " & ".join(latex_escape(c) for c in cols) + " \\\\", "\\hline"]
    for i, r in zip(df.index, df.itertuples(index=False)):
        out.append(" & ".join(latex_escape(x) for x in [str(i)] + [_cell(v) for v in r]) + " \\\\")
    out += ["\\hline", "\\end{tabular}", "\\end{table}"]
    return "\n".join(out)


class ResultsMixin:
    """``bse``, ``conf_int`` and ``propagate`` from a subclass's ``params`` and ``cov_params()``.

    Subclasses define ``params`` (Series), ``_cov`` (ndarray, finite on the
    determined parameters) and ``_bse`` (ndarray with inf / NaN as the module
    docstring says), and ``summary()``.
    """

    @property
    def params(self) -> pd.Series:  # pragma: no cover - abstract
        raise NotImplementedError

    @property
    def bse(self) -> pd.Series:
        return pd.Series(self._bse_array(), index=self.params.index, name="bse")

    def _bse_array(self) -> np.ndarray:  # pragma: no cover - abstract
        raise NotImplementedError

    def _cov_array(self) -> np.ndarray:  # pragma: no cover - abstract
        raise NotImplementedError

    def cov_params(self) -> pd.DataFrame:
        return cov_frame(self._cov_array(), self.params.index, self._bse_array())

    def conf_int(self, alpha: float = 0.05) -> pd.DataFrame:
        if not 0 < alpha < 1:
            raise ValueError(f"alpha must lie in (0, 1), got {alpha!r}")
        z = norm.ppf(1 - alpha / 2)
        p, s = self.params.to_numpy(float), self._bse_array()
        return pd.DataFrame({"lower": p - z * s, "upper": p + z * s}, index=self.params.index)

    @property
    def undetermined_params(self) -> tuple[str, ...]:
        """Names of the parameters the data do not determine (``bse`` inf)."""
        b = self._bse_array()
        return tuple(n for n, s in zip(self.params.index, b) if np.isinf(s))

    def propagate(self, jacobian: np.ndarray | pd.DataFrame) -> np.ndarray:
        """Covariance ``J C J^T`` of quantities with Jacobian ``J`` (m, n_params) w.r.t. ``params``.

        A quantity with a nonzero derivative on an undetermined parameter gets an
        infinite variance; parameters not estimated here (se NaN) count as exact.
        """
        J = np.asarray(jacobian.reindex(columns=self.params.index).fillna(0.0) if isinstance(jacobian, pd.DataFrame) else jacobian, float)
        b = self._bse_array()
        ok = np.isfinite(b)
        C = np.nan_to_num(self._cov_array()[np.ix_(ok, ok)])
        out = J[:, ok] @ C @ J[:, ok].T
        hit = np.any(J[:, np.isinf(b)] != 0, axis=1)
        out[hit, :] = np.nan
        out[:, hit] = np.nan
        out[hit, hit] = np.inf
        return out


class StackedResults(ResultsMixin):
    """Results made of independent parts (one per leg, say): ``params`` concatenated, covariance
    block-diagonal. Subclasses define ``_parts()``, the part results in order."""

    def _parts(self) -> list:  # pragma: no cover - abstract
        raise NotImplementedError

    @property
    def params(self) -> pd.Series:
        parts = self._parts()
        return pd.concat([r.params for r in parts]) if parts else pd.Series(dtype=float)

    def _cov_array(self) -> np.ndarray:
        frames = [r.cov_params().fillna(0.0) for r in self._parts()]
        return block_diag_cov(frames).to_numpy() if frames else np.zeros((0, 0))

    def _bse_array(self) -> np.ndarray:
        parts = self._parts()
        return np.concatenate([r._bse_array() for r in parts]) if parts else np.zeros(0)
