"""The command line: parses options, calls the library, prints. Run ``cfsig --help``."""

from __future__ import annotations

import json
import os
import sys
from collections import Counter
from collections.abc import Callable
from contextlib import contextmanager
from dataclasses import replace
from functools import partial
from pathlib import Path
from typing import TYPE_CHECKING, Any, NoReturn

import click

from cfsig.descriptors import NAMES
from cfsig.errors import CfsigError
from cfsig.isolate import Limits
from cfsig.params import REPAIR_MODES, SOLVERS, Params

if TYPE_CHECKING:  # each command imports what it uses, so that `cfsig --help` starts fast
    from cfsig.descriptors.signature import Signature
    from cfsig.evaluation.collections import Collection, Evaluation
    from cfsig.evaluation.measures import RetrievalReport

EXIT_ERROR = 1
EXIT_SKIPPED = 3
_GRID_COLUMNS = 7  # tiles per row of a single query's --png grid
LOG_SECONDS = 60.0  # the progress bar's redraws into a file (a batch job's log): one a minute
_FILE = click.Path(dir_okay=False, path_type=Path)
_FOLDER = click.Path(file_okay=False, path_type=Path)
_PATH = click.Path(path_type=Path)  # a file or a folder

_params_options = [
    click.option(
        "--normalize/--no-normalize",
        default=None,
        help="Normalise phi to [0, 1] before the histogram (paper section 3.1).",
    ),
    click.option("--seed", type=int, default=None, help="Seed of the surface sampling [0]."),
    click.option("--bins", type=int, default=None, help="Histogram bins [200]."),
    click.option(
        "--repair",
        type=click.Choice(REPAIR_MODES),
        default=None,
        help="A mesh that is not one closed manifold: repair it, else rebuild its outer surface "
        "(auto); always rebuild it (proxy); solve each part as read (off) [auto, or an "
        "existing index's own]. Clean closed manifolds are never changed.",
    ),
]
_descriptor_option = click.option(
    "--descriptor",
    type=click.Choice(NAMES),
    default=None,
    help="What to compute: the spectrum, heat kernel signatures and curvature at scales "
    "(intrinsic); the paper's histogram of the conformal factor (cf); the peers it compares "
    "with: spherical harmonics (sh), the global point signature (gps), the light field (lf), "
    "the augmented multiresolution Reeb graph (amrg); "
    "or, for rigid objects, intrinsic, panoramas and lf weighed together (rigid) [intrinsic, or "
    "an existing index's own].",
)
_solver_option = click.option(
    "--solver",
    type=click.Choice(SOLVERS),
    default="auto",
    show_default=True,
    help="Sparse solver: the fastest installed (auto), CHOLMOD, Eigen (libigl) or SciPy's SuperLU.",
)
_jobs_option = click.option(
    "--jobs",
    "-j",
    type=click.IntRange(min=1),
    default=None,
    help="Worker processes [all cores].",
)
_json_option = click.option("--json", "as_json", is_flag=True, help="Print JSON.")
_stage_timeout_option = click.option(
    "--stage-timeout",
    metavar="SECONDS",
    type=click.FloatRange(min=0, min_open=True),
    default=Limits().seconds,
    show_default=True,
    help="Seconds of wall time allowed to the repair stage's proxy remesh of one mesh; a mesh "
    "that takes longer fails.",
)


def _count_option(*names: str, default: int, help: str) -> Callable:
    """An option taking a positive integer, its default shown in the help."""
    count = click.IntRange(min=1)
    return click.option(*names, type=count, default=default, show_default=True, help=help)


def _with(options: list[Callable]) -> Callable:
    """Apply several click options to a command."""

    def decorate(func: Callable) -> Callable:
        for option in reversed(options):
            func = option(func)
        return func

    return decorate


def _params(base: Params | None = None, **given: Any) -> Params:
    """Parameters from the options that were given, on top of ``base`` or the defaults."""
    given = {k: v for k, v in given.items() if v is not None}
    try:
        return replace(base or Params(), **given)
    except ValueError as exc:
        raise click.BadParameter(str(exc)) from None


def _fail(message: str, code: int = EXIT_ERROR) -> NoReturn:
    """Print one error line and exit."""
    click.echo(f"Error: {message}", err=True)
    sys.exit(code)


def _report_skipped(skipped: list[str], strict: bool) -> None:
    """List the files that failed and exit with the right status."""
    if not skipped:
        return
    click.echo(f"Skipped {len(skipped)} file(s):", err=True)
    for line in skipped:
        click.echo(f"  {line}", err=True)
    sys.exit(EXIT_ERROR if strict else EXIT_SKIPPED)


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="cfsig", prog_name="cfsig")
def main() -> None:
    """Pose-invariant 3D shape retrieval with conformal-factor signatures.

    \b
    Exit status: 0 success; 1 an error (bad input, unusable index, --strict failure);
    2 bad usage; 3 finished, but some mesh files were skipped (listed at the end).
    """


def run() -> NoReturn:
    """The ``cfsig`` command: `main`, then an exit that skips Python's finalization.

    Every command has closed its files and joined its workers by the time `main` returns;
    freeing SciPy, libigl, faiss and the other modules one by one would only make each command
    slower (docs/performance.md, "Partial queries").
    """
    code: str | int | None = 0
    try:
        main()
    except SystemExit as done:
        code = done.code
    if isinstance(code, str):  # as the interpreter does with a message
        print(code, file=sys.stderr)
        code = EXIT_ERROR
    code = code or 0
    try:
        sys.stdout.flush()
        sys.stderr.flush()
    except BrokenPipeError:  # the reader of the output went away
        code = code or EXIT_ERROR
    os._exit(code)


@main.command()
@click.argument("meshes", nargs=-1, required=True, type=_PATH)
@_with(_params_options)
@_descriptor_option
@_solver_option
@_stage_timeout_option
@_json_option
@click.option(
    "--save",
    type=_FOLDER,
    help="Write DIR/<name>.npz with the signature and per-vertex phi.",
)
@click.option(
    "--png",
    type=_FILE,
    help="Draw the meshes side by side coloured by phi scaled to [0, 1].",
)
@click.option(
    "--ply",
    type=_FILE,
    help="Write the mesh with per-vertex colours of phi (one mesh only).",
)
@click.option(
    "--hist",
    type=_FILE,
    help="Plot the signature histograms overlaid.",
)
def compute(
    meshes,
    normalize,
    seed,
    bins,
    repair,
    descriptor,
    solver,
    stage_timeout,
    as_json,
    save,
    png,
    ply,
    hist,
) -> None:
    """Compute the conformal factor and signature of each mesh.

    \b
    Example:
      cfsig compute human/1.off hand/181.off
      cfsig compute --json --save out/ spring/261.off
      cfsig compute hand/181.off human/1.off --png phi.png --hist hist.png
    """
    if ply and len(meshes) > 1:
        raise click.UsageError("--ply writes one mesh: give a single MESH")
    params = _params(
        normalize=normalize, seed=seed, bins=bins, repair=repair, descriptor=descriptor
    )
    if hist and params.descriptor != "cf":
        raise click.UsageError("--hist plots the histograms of the cf descriptor")
    import numpy as np

    from cfsig.descriptors.signature import mesh_and_signature

    rows: list[dict] = []
    failed: list[str] = []
    drawn: list = []
    for path in meshes:
        try:
            mesh, sig = mesh_and_signature(
                path, params, solver, phi=True, limits=Limits(stage_timeout)
            )
        except CfsigError as exc:
            failed.append(str(exc))
            rows.append({"file": str(path), "error": str(exc)})
            continue
        if png or ply or hist:
            drawn.append((path, mesh, sig))
        for repair in sig.repairs:
            click.echo(f"Warning: {path}: {repair}", err=True)
        row = _describe(path, sig)
        rows.append(row)
        if save:
            assert sig.phi is not None  # solved for compute (phi=True)
            save.mkdir(parents=True, exist_ok=True)
            arrays: dict[str, Any] = {"signature": sig.vector, "phi": sig.phi}
            if sig.cells is not None:
                arrays["cells"], arrays["cell_units"] = sig.cells
            np.savez(save / f"{path.stem}.npz", params=params.to_json(), **arrays)
        if not as_json:
            click.echo(
                f"{path}: {row['vertices']} vertices, {row['faces']} faces, "
                f"{row['components']} component(s), phi in [{row['phi_min']:.3f}, "
                f"{row['phi_max']:.3f}], curvature error {row['curvature_error']:.2e} pi, "
                f"{row['seconds']:.3f} s" + ("" if sig.route == "clean" else f", {sig.route}")
            )
    if as_json:
        click.echo(json.dumps(rows, indent=2))
    if drawn:
        _compute_pictures(drawn, params, png, ply, hist)
    _report_errors(failed)


def _describe(path: Path, sig: Signature) -> dict:
    """The facts `compute` reports about one signature."""
    low, high = sig.phi_range
    return {
        "file": str(path),
        "vertices": sig.n_vertices,
        "faces": sig.n_faces,
        "components": sig.n_components,
        "phi_min": low,
        "phi_max": high,
        "curvature_error": sig.curvature_error,
        "seconds": sig.seconds,
        "route": sig.route,
        "repairs": list(sig.repairs),
    }


def _report_errors(errors: list[str]) -> None:
    """Print failures of single-file commands and exit with status 1 if there were any."""
    for line in errors:
        click.echo(f"Error: {line}", err=True)
    if errors:
        sys.exit(EXIT_ERROR)


@main.command()
@click.argument("paths", nargs=-1, required=True, type=_PATH)
@click.option(
    "-o",
    "--output",
    required=True,
    type=_PATH,
    help="The index (a folder of HDF5 files); created, or updated with new and changed meshes.",
)
@_with(_params_options)
@_descriptor_option
@_solver_option
@_stage_timeout_option
@_jobs_option
@click.option(
    "--scheduler", metavar="ADDRESS",
    help="Compute on the workers of a running Dask cluster (tcp://host:port) instead of local "
    "processes; the mesh paths must be readable on the workers. Needs the dask extra.",
)  # fmt: skip
@click.option("--strict", is_flag=True, help="Stop at the first file that fails.")
@click.option(
    "--partial-cells/--no-partial-cells",
    default=None,
    help="Keep each mesh's fine curvature cells (intrinsic only, about 6 KB a mesh), which "
    "partial queries then rank by: right far more often on parts of people and animals, at "
    "a cost over large indexes (docs/performance.md) [no, or an existing index's own].",
)
@_count_option(
    "--commit-every",
    default=200,
    help="Commit to the index after this many meshes (and every 30 s).",
)
@click.option(
    "--classes",
    type=_FILE,
    help="Label meshes by a Princeton Shape Benchmark .cla file instead of their folder's name "
    "(indexed ones too, without recomputing them); those it does not list keep the folder's.",
)
@click.option(
    "--prune",
    is_flag=True,
    help="Also drop the entries whose file, under the folders given, no longer exists.",
)
def index(
    paths,
    output,
    normalize,
    seed,
    bins,
    repair,
    descriptor,
    solver,
    stage_timeout,
    jobs,
    scheduler,
    strict,
    partial_cells,
    commit_every,
    classes,
    prune,
) -> None:
    """Index mesh files and folders (recursively: OFF, OBJ, PLY, STL, glTF, GLB, 3MF, DAE).

    The index is a folder, created if needed.

    Each mesh is stored under its path relative to the folder given, labelled with the name of
    the folder that holds it (or its class in --classes). Links to folders and files are
    followed. Running the command again adds new and changed files only; entries are dropped
    only with --prune. Files that fail are skipped and listed at the end (exit status 3). The
    index is committed atomically as it grows: after a crash or a kill, running the same
    command again completes it without recomputing what was committed.

    \b
    Example:
      cfsig index shrec07/ -o shrec07-index --jobs 2
      cfsig index shrec07/ -o shrec07-index --prune --classes shrec07.cla
      cfsig index /shared/shrec07/ -o shrec07-index --scheduler tcp://10.0.0.5:8786
    """
    if jobs is not None and scheduler is not None:
        raise click.UsageError("give --jobs or --scheduler, not both")
    from cfsig.batch import check_inputs, index_meshes
    from cfsig.descriptors import layout
    from cfsig.errors import UnknownNameError
    from cfsig.index.store import IndexWriter, existing_params

    cla = _read_classes(classes)
    routes: Counter[str] = Counter()
    try:
        check_inputs(output, paths, cla)
        params = _params(
            existing_params(output), normalize=normalize, seed=seed, bins=bins, repair=repair,
            descriptor=descriptor, partial_cells=partial_cells,
        )  # fmt: skip
        with IndexWriter(output, params, layout(params)) as writer:
            bar = partial(_progress, what="indexing", routes=routes)
            done = index_meshes(
                writer, paths, solver, jobs, scheduler, strict, commit_every, bar,
                Limits(stage_timeout), cla, prune,
            )  # fmt: skip
        total = len(writer)  # after the last commit
    except UnknownNameError as exc:  # of the classes
        _fail(f"{classes}: {exc}")
    except CfsigError as exc:
        _fail(str(exc))
    changes = [f"{done.added} meshes added or updated"]
    changes += [f"{done.updated} relabelled or moved"] if classes or done.updated else []
    changes += [f"{done.pruned} dropped (their files are gone)"] if prune else []
    click.echo(f"{output}: {', '.join(changes)}, {total} in the index")
    if routes:
        click.echo(_format_routes(routes))
    _report_skipped(done.failures, strict)


def _read_classes(path: Path | None) -> dict[str, str] | None:
    """The classes of a .cla file given as an option, or exit with one line saying why not."""
    from cfsig.files.cla import read_cla

    try:
        return read_cla(path) if path else None
    except OSError as exc:
        _fail(f"{path}: {exc.strerror or exc}")
    except ValueError as exc:  # names the file and line already
        _fail(str(exc))


def _progress(iterable, total: Callable[[], int], what: str, routes: Counter[str]):
    """A tqdm progress bar on standard error, counting the repair routes of what passes.

    Its total is the number of files found so far: it grows while a folder is being scanned,
    and shows at the bar's next redraw. The bar is redrawn up to ten times a second on a
    terminal, and once every `LOG_SECONDS` into a file, so that a batch job's log stays small.
    """
    from tqdm import tqdm

    interval = 0.1 if sys.stderr.isatty() else LOG_SECONDS
    bar = tqdm(
        iterable, total=total(), desc=what, unit="mesh", file=sys.stderr, leave=False,
        mininterval=interval, maxinterval=max(interval, 10.0),
    )  # fmt: skip
    for outcome in bar:
        bar.total = total()
        if outcome.signature is not None:
            routes[outcome.signature.route] += 1
        yield outcome


def _format_routes(routes: Counter[str]) -> str:
    """How many meshes took each route of the repair stage, in one line."""
    order = ("clean", "repaired", "proxy", "unrepaired")
    return "repair: " + ", ".join(f"{routes[r]} {r}" for r in order if routes[r])


@main.command()
@click.argument("index_file", type=_PATH)
@click.argument("meshes", nargs=-1, type=_PATH)
@click.option(
    "--name",
    "names",
    multiple=True,
    help="Query by an indexed entry's stored signature instead of a file, itself left out of "
    "its results (repeatable).",
)
@_count_option("-k", default=20, help="Number of results per query.")
@_solver_option
@_stage_timeout_option
@_json_option
@click.option(
    "--png",
    type=_FILE,
    help="Draw each query and its results as framed thumbnails.",
)
@click.option(
    "--partial",
    is_flag=True,
    help="Each query is a part of a shape (a cut, a scan, holes): find the wholes it belongs to.",
)
def query(index_file, meshes, names, k, solver, stage_timeout, as_json, png, partial) -> None:
    """Find the k indexed meshes nearest to each query mesh (L1; lf, rigid, amrg: their own).

    With --name, the queries are indexed entries, by the signatures stored: no file is read,
    and each is left out of its own results.

    The query signatures are computed with the index's own parameters. With --partial the
    first result is the whole whose curvature at small scales matches the part's best (its
    partial distance, 0 to 3, follows the query's name in the text output and is the first
    result's "partial_distance" in the JSON), the others the
    meshes nearest to that whole, with their distances to it (docs/method.md); it needs an
    index of the intrinsic descriptor, and ranks by fine curvature cells where the index keeps
    them (cfsig index --partial-cells). In the --png picture a query whose folder
    name is a class of the index has its results framed green (same class) or orange.

    \b
    Example:
      cfsig query shrec07-index shrec07/ant/81.off -k 10
      cfsig query shrec07-index shrec07/ant/81.off --png ant.png
      cfsig query shrec07-index --name ant/81.off
      cfsig query shrec07-index scan.ply --partial
    """
    if bool(meshes) == bool(names):
        raise click.UsageError("give MESH files or --name, not both")
    if names and partial:
        raise click.UsageError("--partial takes MESH files: parts are not indexed")
    import numpy as np

    from cfsig.descriptors.parts import partial_file
    from cfsig.descriptors.signature import signature_file
    from cfsig.index.store import IndexReader
    from cfsig.search.nearest import query, query_names
    from cfsig.search.partial import query_part

    try:
        with IndexReader(index_file) as reader:
            fits: list[float] = []
            if names:
                results = query_names(reader, list(names), k)
                meshes = [Path(e.path) for e in reader.entries(reader.find(list(names)))]
            elif partial:
                found = [query_part(reader, partial_file(p, reader.params), k) for p in meshes]
                results, fits = [hits for hits, _ in found], [fit for _, fit in found]
            else:
                limits = Limits(stage_timeout)
                sigs = [signature_file(p, reader.params, solver, limits).vector for p in meshes]
                results = query(reader, np.array(sigs), k)
            classes = set(reader.column("labels")) if png else set()
    except CfsigError as exc:
        _fail(str(exc))
    if png:
        _query_picture(png, meshes, results, classes)
    if as_json:
        lists = [
            [
                {
                    "rank": h.rank,
                    "distance": h.distance,
                    "name": h.entry.name,
                    "label": h.entry.label,
                }
                for h in hits
            ]
            for hits in results
        ]
        for rows, fit in zip(lists, fits, strict=False):  # fits: none without --partial
            if rows:
                rows[0]["partial_distance"] = fit
        click.echo(json.dumps(lists[0] if len(lists) == 1 else lists, indent=2))
        return
    for i, (path, hits) in enumerate(zip(names or meshes, results, strict=True)):
        click.echo(f"# {path}" + (f"  (partial distance {fits[i]:.4f})" if fits else ""))
        for h in hits:
            click.echo(f"{h.rank:4d}  {h.distance:.4f}  {h.entry.name}  {h.entry.label}")


@main.command()
@click.argument("folder", required=False, type=_FOLDER)
@click.option(
    "--classes",
    type=_FILE,
    help="Classes from a Princeton Shape Benchmark .cla file instead of subfolders.",
)
@click.option(
    "--index",
    "index_file",
    type=_PATH,
    help="Evaluate the signatures of an index instead of computing them.",
)
@click.option(
    "--descriptor",
    "descriptors",
    help=f"Descriptors to compare side by side, comma-separated ({', '.join(NAMES)}) "
    f"[{NAMES[0]}; with --index, the index's own].",
)
@_with(_params_options)
@_solver_option
@_stage_timeout_option
@_jobs_option
@click.option("--strict", is_flag=True, help="Stop at the first file that fails.")
@_json_option
@click.option(
    "--plot",
    type=_FOLDER,
    help="Write DIR/precision_recall.png, the precision/recall curves overall and per class "
    "(a curve per descriptor), and per class DIR/query_*.png, its first model's nearest (a row "
    "per descriptor).",
)
@click.option(
    "--report",
    "report_dir",
    type=_FOLDER,
    help="Write DIR/index.html: measures, curves and one query per class.",
)
@click.option(
    "--partial",
    "parts",
    type=_FOLDER,
    help="With --index: evaluate the parts in this folder (one subfolder per class) as "
    "partial queries against the index's whole shapes.",
)
def evaluate(
    folder,
    classes,
    index_file,
    descriptors,
    normalize,
    seed,
    bins,
    repair,
    solver,
    stage_timeout,
    jobs,
    strict,
    as_json,
    plot,
    report_dir,
    parts,
) -> None:
    """Retrieval measures of a labelled collection (leave-one-out).

    Each subfolder of FOLDER is a class (or --classes maps file ids to classes). Prints the
    Princeton Shape Benchmark / SHREC measures NN, FT, ST, E, DCG and mAP, overall and per
    class, the precision/recall curve and the median seconds per mesh (reading included).
    With several descriptors, prints them side by side on the meshes that all of them could
    compute: the measures, the first tier (FT) per class and the seconds per mesh.

    \b
    Example:
      cfsig evaluate shrec07/
      cfsig evaluate shrec07/ --descriptor cf,intrinsic
      cfsig evaluate shrec07/ --classes shrec07.cla --json
      cfsig evaluate shrec07/ --descriptor cf,sh,gps,intrinsic --plot figures/
      cfsig evaluate --index shrec07-index --report report/
      cfsig evaluate --index shrec07-index --partial scans/
    """
    if (folder is None) == (index_file is None):
        raise click.UsageError("give a FOLDER or --index, not both")
    if parts:
        if not index_file or classes or plot or report_dir or descriptors:
            raise click.UsageError("--partial takes --index, --json and --jobs only")
        _evaluate_partial(index_file, parts, as_json, jobs)
        return
    if index_file and descriptors:
        raise click.UsageError("--descriptor is for a FOLDER: an index holds one descriptor")
    wanted = _descriptor_list(descriptors)
    if len(wanted) > 1 and report_dir:
        raise click.UsageError("--report takes one descriptor")
    from cfsig.evaluation.collections import collection_from_index, evaluate_collections

    cla = _read_classes(classes)
    skipped: list[str] = []
    routes: dict[str, Counter[str]] = {}  # per descriptor: their repair modes may differ
    collections: dict[str, Collection] = {}
    try:
        if index_file:
            collections = dict([collection_from_index(index_file)])
        else:
            limits = Limits(stage_timeout)
            for name in wanted:
                params = _params(
                    normalize=normalize, seed=seed, bins=bins, repair=repair, descriptor=name
                )
                routes[name] = Counter()
                collections[name] = _compute_folder(
                    folder, params, solver, jobs, strict, skipped, routes[name], limits
                )
    except CfsigError as exc:
        _fail(str(exc))
    try:
        results = evaluate_collections(collections, cla)
    except ValueError as exc:
        _fail(f"{index_file or folder}: {exc}")
    if len(results) == 1:
        (result,) = results.values()
        report = result.report
        if as_json:
            computed = (
                {"repair": dict(routes[wanted[0]]), "seconds_per_mesh": result.seconds_per_mesh}
                if folder
                else {}
            )
            click.echo(json.dumps({**report.to_dict(), **computed}, indent=2))
        else:
            click.echo(_format_report(report))
        if result.seconds_per_mesh is not None and not as_json:
            click.echo(f"median seconds per mesh: {result.seconds_per_mesh:.3f}")
    elif as_json:
        out = {
            name: {
                **r.report.to_dict(),
                "seconds_per_mesh": r.seconds_per_mesh,
                "repair": dict(routes[name]),
            }
            for name, r in results.items()
        }
        click.echo(json.dumps(out, indent=2))
    else:
        click.echo(_format_side_by_side(results))
    for name, counted in routes.items():
        if counted and not as_json:
            click.echo(("" if len(routes) == 1 else f"{name} ") + _format_routes(counted))
    _evaluate_pictures(plot, report_dir, results)
    _report_skipped(skipped, strict)


def _evaluate_partial(index_file: Path, parts: Path, as_json: bool, jobs: int | None) -> None:
    """Print the measures of partial queries against an index, and the parts that failed."""
    from cfsig.evaluation.collections import evaluate_partial

    try:
        report, failures = evaluate_partial(index_file, parts, jobs)
    except CfsigError as exc:
        _fail(str(exc))
    except ValueError as exc:
        _fail(f"{parts}: {exc}")
    click.echo(json.dumps(report.to_dict(), indent=2) if as_json else _format_report(report))
    _report_skipped(failures, strict=False)


def _descriptor_list(text: str | None) -> list[str]:
    """The distinct descriptor names of a comma-separated ``--descriptor`` value."""
    names = [d.strip() for d in (text or NAMES[0]).split(",") if d.strip()]
    if not names or set(names) - set(NAMES) or len(set(names)) < len(names):
        raise click.BadParameter(
            f"{text!r}: give distinct names from {', '.join(NAMES)}",
            param_hint="--descriptor",
        )
    return names


def _compute_folder(
    folder: Path,
    params: Params,
    solver: str,
    jobs,
    strict: bool,
    skipped: list[str],
    routes: Counter[str],
    limits: Limits,
) -> Collection:
    """A folder's collection under a progress bar; failures go to ``skipped``, exit if none."""
    from cfsig.evaluation.collections import compute_collection

    bar = partial(_progress, what=f"computing {params.descriptor}", routes=routes)
    collection, failures = compute_collection(folder, params, solver, jobs, strict, bar, limits)
    skipped += failures
    if not len(collection) or (strict and failures):
        _report_skipped(skipped, strict)
    return collection


def _format_side_by_side(results: dict[str, Evaluation]) -> str:
    """Several descriptors' measures, per-class first tier and seconds per mesh as text."""
    reports = {name: result.report for name, result in results.items()}
    first = next(iter(reports.values()))
    keys = list(first.measures)
    lines = [f"{first.count} queries", f"{'descriptor':<16}" + "".join(f"{k:>8}" for k in keys)]
    lines[-1] += f"{'s/mesh':>9}"
    for name, report in reports.items():
        values = "".join(f"{report.measures[k]:8.3f}" for k in keys)
        lines.append(f"{name:<16}{values}{results[name].seconds_per_mesh:9.3f}")
    lines += ["first tier (FT) per class:", f"{'class':<16}" + "".join(f"{n:>8}" for n in reports)]
    for cls in sorted(first.per_class):
        lines.append(
            f"{cls:<16}" + "".join(f"{r.per_class[cls]['FT']:8.3f}" for r in reports.values())
        )
    return "\n".join(lines)


def _format_report(report: RetrievalReport) -> str:
    """The measures as text tables."""
    keys = list(report.measures)
    lines = [f"{report.count} queries", f"{'class':<16}" + "".join(f"{k:>8}" for k in keys)]
    rows = [("ALL", report.measures), *sorted(report.per_class.items())]
    lines += [f"{name:<16}" + "".join(f"{m[k]:8.3f}" for k in keys) for name, m in rows]
    curve = "  ".join(f"{r:.2f}:{p:.3f}" for r, p in report.precision_recall)
    return "\n".join([*lines, "precision at recall:", curve])


@main.command()
@click.argument("index_file", type=_PATH)
def check(index_file) -> None:
    """Verify every checksum of an index and name what is damaged.

    Reads the whole index: the manifest, and each segment's file, signature chunks and
    columns. Exit status 0 when healthy, 1 when something is damaged (listed) or unreadable.

    \b
    Example:
      cfsig check shrec07-index
    """
    from cfsig.index.store import IndexReader, check_index

    try:
        problems = check_index(index_file)
        if not problems:
            with IndexReader(index_file) as reader:
                rows, segments = len(reader), len(reader.segments)
    except CfsigError as exc:
        _fail(str(exc))
    if problems:
        click.echo(f"{index_file}: damaged:", err=True)
        for line in problems:
            click.echo(f"  {line}", err=True)
        sys.exit(EXIT_ERROR)
    click.echo(f"{index_file}: healthy ({rows} entries in {segments} segment(s))")


@main.command()
@click.argument("index_file", type=_PATH)
@click.argument("names", nargs=-1, required=True)
def remove(index_file, names) -> None:
    """Drop the named entries from an index, atomically.

    Queries stop finding them at once; their rows leave the disk at the next compaction. A name
    that is not in the index is an error, and nothing is removed.

    \b
    Example:
      cfsig remove shrec07-index ant/81.off ant/82.off
    """
    from cfsig.index.store import IndexWriter, read_manifest

    try:
        with IndexWriter(index_file, read_manifest(Path(index_file)).params) as writer:
            writer.remove(names)
        total = len(writer)
    except CfsigError as exc:
        _fail(str(exc))
    click.echo(f"{index_file}: {len(set(names))} entries removed, {total} in the index")


@main.command()
@click.argument("index_file", type=_PATH)
@_json_option
def info(index_file, as_json) -> None:
    """What an index holds: its descriptor and parameters, entries per class, size, version.

    Reads the manifest and the sizes of the files only.

    \b
    Example:
      cfsig info shrec07-index
    """
    from cfsig.index.store import index_info

    try:
        facts = index_info(index_file).to_dict()
    except CfsigError as exc:
        _fail(str(exc))
    if as_json:
        click.echo(json.dumps(facts, indent=2))
        return
    params = ", ".join(f"{k}={v}" for k, v in facts["params"].items() if k != "descriptor")
    lines = [
        f"index          {facts['index']}",
        f"descriptor     {facts['descriptor']} ({params})",
        f"partial cells  {'kept' if facts['partial_cells'] else 'no'}",
        f"entries        {facts['rows']} in {len(facts['classes'])} classes",
        f"segments       {facts['segments']}, {facts['bytes']:,} bytes on disk",
        f"written by     cfsig {facts['cfsig_version']}, last committed {facts['committed']}",
        "classes:",
        *(f"  {label or '(none)':<24}{count:>8}" for label, count in facts["classes"].items()),
    ]
    click.echo("\n".join(lines))


@main.command()
@click.argument("index_file", type=_PATH)
@click.option(
    "--below",
    type=click.FloatRange(min=0, min_open=True),
    help="Join entries closer than this [0.2, for the intrinsic descriptor; others: give it].",
)
@click.option(
    "--top", type=click.IntRange(min=1), help="Instead: list each entry's K nearest others."
)
@_json_option
def duplicates(index_file, below, top, as_json) -> None:
    """Near-duplicates of a whole index: groups of entries closer than a distance.

    Every entry is a query against the index, by the search `query` makes (pruned, exact),
    streamed with bounded memory; a progress bar runs on standard error. Entries join a group
    when they are closer than --below, directly or through others of the group. The default
    finds copies of one model re-saved, moved, rotated and scaled (docs/guide.md says how it
    was chosen). With --top K, prints each entry's K nearest others instead, as they come.

    \b
    Example:
      cfsig duplicates shrec07-index
      cfsig duplicates shrec07-index --top 10 --json > neighbours.json
    """
    from tqdm import tqdm

    from cfsig.index.store import IndexReader
    from cfsig.search.duplicates import BELOW, duplicate_groups, nearest_all

    if top and below:
        raise click.UsageError("give --below or --top, not both")
    try:
        with IndexReader(index_file) as reader:
            if below is None and not top and reader.params.descriptor != Params().descriptor:
                raise click.UsageError(
                    f"the default --below is for {Params().descriptor}: give one for "
                    f"{reader.params.descriptor}"
                )
            with tqdm(total=len(reader), unit="mesh", file=sys.stderr, leave=False) as bar:
                if top:
                    _print_neighbours(nearest_all(reader, top, bar.update), as_json)
                    return
                groups = duplicate_groups(reader, below or BELOW, bar.update)
    except CfsigError as exc:
        _fail(str(exc))
    if as_json:
        out = [
            {"distance": g.distance, "names": [e.name for e in g.entries],
             "labels": [e.label for e in g.entries]}
            for g in groups
        ]  # fmt: skip
        click.echo(json.dumps(out, indent=2))
        return
    for i, group in enumerate(groups, 1):
        click.echo(f"# group {i}: {len(group.entries)} entries, joined below {group.distance:.4f}")
        for entry in group.entries:
            click.echo(f"{entry.name}  {entry.label}")
    click.echo(f"{index_file}: {len(groups)} groups of near-duplicates")


def _print_neighbours(found, as_json: bool) -> None:
    """Print each entry's nearest others as they come: text, or one JSON list written as it
    grows."""
    if as_json:
        click.echo("[")
    for i, (entry, hits) in enumerate(found):
        if as_json:
            near = [{"rank": h.rank, "distance": h.distance, "name": h.entry.name} for h in hits]
            item = json.dumps({"name": entry.name, "label": entry.label, "nearest": near})
            click.echo(("," if i else "") + item)
            continue
        click.echo(f"# {entry.name}")
        for h in hits:
            click.echo(f"{h.rank:4d}  {h.distance:.4f}  {h.entry.name}  {h.entry.label}")
    if as_json:
        click.echo("]")


@main.command()
@click.argument("index_file", type=_PATH)
def compact(index_file) -> None:
    """Merge an index's segments into one, dropping superseded rows.

    Commits merge small segments automatically; this merges everything, checking each
    segment's checksums as it reads it. Safe to kill: the index stays as it was until the new
    segment is published. Readers keep answering meanwhile.

    \b
    Example:
      cfsig compact shrec07-index
    """
    from cfsig.index.store import compact_index

    try:
        before, rows = compact_index(index_file)
    except CfsigError as exc:
        _fail(str(exc))
    click.echo(f"{index_file}: {before} segment(s) merged into 1, {rows} entries")


@main.command()
@click.option(
    "--out",
    type=_FOLDER,
    default="cfsig-demo",
    show_default=True,
    help="Folder for the generated meshes and the index.",
)
@click.pass_context
def demo(ctx: click.Context, out: Path) -> None:
    """Run cfsig end to end on a generated collection: index, query, evaluate.

    Writes 30 synthetic meshes in 6 classes (bodies with 1, 2, 3 and 5 limbs, tori, capsules;
    5 poses each) to OUT, indexes them into OUT/index, queries with one mesh of each of two
    classes, and prints the retrieval measures.

    \b
    Example:
      cfsig demo --out /tmp/cfsig-demo
    """
    from cfsig.files.demo import make_demo_collection

    paths = make_demo_collection(out / "meshes")
    click.echo(f"Wrote {len(paths)} meshes to {out / 'meshes'}")
    index_file = out / "index"
    ctx.invoke(index, paths=(out / "meshes",), output=index_file)
    queries = (paths[0], paths[len(paths) // 2])
    ctx.invoke(query, index_file=index_file, meshes=queries, k=5)
    ctx.invoke(evaluate, index_file=index_file)


def _short(path: Path) -> str:
    """A mesh file's folder and name, e.g. ``hand/181.off``, to caption a picture."""
    return f"{path.parent.name}/{path.name}" if path.parent.name else path.name


@contextmanager
def _writing_pictures():
    """Turn failures to draw or write a picture into one error line."""
    try:
        yield
    except CfsigError as exc:
        _fail(str(exc))
    except OSError as exc:
        _fail(f"{exc.filename}: cannot write: {exc.strerror or exc}")


def _warn_undrawn(problems: list[str]) -> None:
    """One warning line per mesh file that a picture shows as a placeholder."""
    for line in problems:
        click.echo(f"Warning: {line}", err=True)


def _compute_pictures(drawn: list, params: Params, png, ply, hist) -> None:
    """The pictures of `compute`: phi on the meshes, a coloured PLY, the histograms."""
    from cfsig.figures import plots as figures

    with _writing_pictures():
        if png:
            shown = [(path, _short(path), mesh, sig.phi, sig.route) for path, mesh, sig in drawn]
            items, views = figures.phi_panels(shown)
            figures.render_phi(items, png, views=views)
        if ply:
            _, mesh, sig = drawn[0]
            figures.write_ply(mesh, sig.phi, ply)
        if hist:
            names = [_short(path) for path, _, _ in drawn]
            hists = [sig.vector for _, _, sig in drawn]
            figures.plot_histograms(hists, names, params.edges, hist)


def _query_picture(png: Path, meshes, results, classes: set[str]) -> None:
    """The grid of each query (one row per query, wrapped) and its results."""
    from cfsig.figures import plots as figures
    from cfsig.files.folders import mesh_label

    rows = []
    for path, hits in zip(meshes, results, strict=True):
        label = mesh_label(path) if mesh_label(path) in classes else None
        tiles = figures.retrieval_row(
            (str(path), _short(path), label),
            [(h.entry.path, h.entry.name, h.entry.label, h.distance) for h in hits],
        )
        width = len(tiles) if len(meshes) > 1 else min(len(tiles), _GRID_COLUMNS)
        rows += [tiles[i : i + width] for i in range(0, len(tiles), width)]
    with _writing_pictures():
        _warn_undrawn(figures.render_grid(rows, png))


def _evaluate_pictures(plot, report_dir, results: dict[str, Evaluation]) -> None:
    """The pictures of `evaluate`: the comparison of its descriptors, the one's HTML report."""
    from cfsig.figures.report import write_comparison, write_report

    with _writing_pictures():
        if plot:
            _warn_undrawn(write_comparison(plot, results))
        if report_dir:
            (result,) = results.values()
            kept = result.collection
            columns = (kept.names, kept.labels, kept.paths)
            _warn_undrawn(write_report(report_dir, result.report, *columns, result.distances))
