"""The usdview side of the plugin: menu entries and Qt dialogs around commands.py."""
from pxr import Tf
from pxr.Usdviewq.plugin import PluginContainer

from . import commands


def _show(usdviewApi, title, text):
    from pxr.Usdviewq.qt import QtWidgets
    usdviewApi.PrintStatus(text.splitlines()[0] if text else title)
    QtWidgets.QMessageBox.information(usdviewApi.qMainWindow, title, text)


def _error(usdviewApi, title, err):
    from pxr.Usdviewq.qt import QtWidgets
    QtWidgets.QMessageBox.warning(usdviewApi.qMainWindow, title, f"error: {err}")


def _statistics(usdviewApi):
    try:
        _show(usdviewApi, "Granular statistics", commands.statistics_text(usdviewApi.stage, usdviewApi.selectedPaths))
    except Exception as e:  # a user error names the prim and attribute
        _error(usdviewApi, "Granular statistics", e)


def _light_links(usdviewApi):
    try:
        _show(usdviewApi, "Light links", commands.light_links_text(usdviewApi.stage, usdviewApi.selectedPaths))
    except Exception as e:  # a user error names the prim and attribute
        _error(usdviewApi, "Light links", e)


def _export(usdviewApi):
    from pxr.Usdviewq.qt import QtWidgets
    paths = [str(p) for p in usdviewApi.selectedPaths]
    if not paths:
        _error(usdviewApi, "Export coarse density", "select a granular aggregate first")
        return
    out, _ = QtWidgets.QFileDialog.getSaveFileName(usdviewApi.qMainWindow, "Export coarse density",
                                                   commands.default_vdb_name(usdviewApi.stage, paths[0]),
                                                   "OpenVDB (*.vdb)")
    if not out:
        return
    try:
        _show(usdviewApi, "Export coarse density", commands.export_density_text(usdviewApi.stage, paths[0], out))
    except Exception as e:
        _error(usdviewApi, "Export coarse density", e)


def _toggle_reference(usdviewApi):
    # usdview's API offers no renderer-setting setter; its stage view, a child widget of
    # the main window, does (the Hydra Settings dialog uses it too).
    from pxr.Usdviewq.stageView import StageView
    view = usdviewApi.qMainWindow.findChild(StageView)
    if view is None or not hasattr(view, "SetRendererSetting"):
        _error(usdviewApi, "EPT reference", "this usdview has no renderer settings")
        return
    new = commands.toggled_technique(view.GetRendererSetting(commands.TECHNIQUE_SETTING))
    view.SetRendererSetting(commands.TECHNIQUE_SETTING, new)
    usdviewApi.PrintStatus(f"Granular technique: {new}")
    view.updateView()


class GranularPluginContainer(PluginContainer):
    def registerPlugins(self, plugRegistry, usdviewApi):
        self._statistics = plugRegistry.registerCommandPlugin(
            "GranularPluginContainer.statistics", "Statistics of Selected Prim", _statistics)
        self._links = plugRegistry.registerCommandPlugin(
            "GranularPluginContainer.lightLinks", "Light Links of Selected Light", _light_links)
        self._export = plugRegistry.registerCommandPlugin(
            "GranularPluginContainer.exportDensity", "Export Coarse Density to VDB...", _export)
        self._reference = plugRegistry.registerCommandPlugin(
            "GranularPluginContainer.toggleReference", "Toggle EPT-only Reference", _toggle_reference)

    def configureView(self, plugRegistry, plugUIBuilder):
        menu = plugUIBuilder.findOrCreateMenu("Granular")
        menu.addItem(self._statistics)
        menu.addItem(self._links)
        menu.addItem(self._export)
        menu.addSeparator()
        menu.addItem(self._reference)


Tf.Type.Define(GranularPluginContainer)
