"""``esense view``: look at a mesh, a scene or a surface solution file.

Examples::

    esense view sensor.vtp                      # a window, where a display exists
    esense view scene.vtp --png scene.png       # a picture, no display needed
    esense view solution.vtp --scalars potential_V --png potential.png
    esense view scene.vtp --html scene.html     # needs trame: pip install "electrosense[html]"

A file with a cell array ``electrode`` is drawn by label (electrodes in
colour, insulator grey, tank translucent, objects bronze) unless
``--scalars`` names a data array; any other surface is coloured by its
first data array.
"""
from __future__ import annotations

import os
import sys

import click


def has_display() -> bool:
    """Whether an interactive window can open (a display on Linux; always on macOS and Windows)."""
    if sys.platform.startswith("linux"):
        return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))
    return True


def _html_available() -> bool:
    import importlib.util

    return importlib.util.find_spec("trame") is not None


@click.command("view")
@click.argument("file", type=click.Path(exists=True, dir_okay=False))
@click.option("--png", type=click.Path(dir_okay=False), default=None, help="Write a picture (PNG) instead of a window.")
@click.option("--html", type=click.Path(dir_okay=False), default=None,
              help="Write an interactive HTML page (needs the optional dependency trame: "
                   "pip install \"electrosense[html]\").")
@click.option("--scalars", default=None,
              help="Colour by this cell or point array (default: by electrode for a labelled mesh, else the first array).")
@click.option("--title", default=None, help="Heading of the picture (default: the file name).")
def view(file, png, html, scalars, title):
    """Show FILE (.vtp, .vtk, .ply, .stl...): a labelled mesh, a scene or a surface solution."""
    from pathlib import Path

    if html and not _html_available():
        raise click.ClickException(
            "--html needs the optional dependency trame, which is not installed: "
            "pip install \"electrosense[html]\" (or use --png)"
        )
    interactive = not png and not html
    if interactive and not has_display():
        raise click.ClickException("no display to open a window on: give --png FILE (or --html FILE)")

    if not interactive:  # a window on the display renders by itself; pictures need EGL or OSMesa
        from electrosense.meshes.render import RenderUnavailable, require_3d

        try:
            require_3d()
        except RenderUnavailable as exc:
            raise click.ClickException(str(exc)) from None
    import pyvista as pv

    from electrosense.meshes.io import from_polydata, read_mesh
    from electrosense.meshes.render import data_plotter, mesh_plotter

    title = title or Path(file).name
    suffix = Path(file).suffix.lower()
    try:
        if suffix in (".ply", ".stl", ".obj"):
            labelled = read_mesh(file, require_electrode=False)
            poly = None
        else:
            poly = pv.read(file)
            labelled = from_polydata(poly, file, require_electrode=False) if "electrode" in poly.cell_data else None
    except Exception as exc:  # unreadable files: say which and why
        raise click.ClickException(f"{file}: cannot be read ({exc})") from None
    if poly is not None and not isinstance(poly, pv.PolyData):
        poly = poly.extract_surface()

    def make_plotter(off_screen: bool):
        if labelled is not None and scalars is None:
            return mesh_plotter(labelled, title=title, off_screen=off_screen)
        if poly is None:
            raise click.ClickException(f"{file}: no data arrays to colour by; drop --scalars")
        try:
            return data_plotter(poly, scalars, title=title, off_screen=off_screen)
        except ValueError as exc:
            raise click.ClickException(f"{file}: {exc}") from None

    if png:
        plotter = make_plotter(True)
        plotter.screenshot(png)
        plotter.close()
        click.echo(f"wrote {png}")
    if html:
        plotter = make_plotter(True)
        plotter.export_html(html)
        plotter.close()
        click.echo(f"wrote {html}")
    if interactive:
        make_plotter(False).show()
