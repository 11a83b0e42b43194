"""Run inside a real usdview by `testusdview --testScript` (tests/hydra/usdview_check.py
drives it): select the Granular renderer's view of the stage's camera, wait for the
converged image, grab the viewport, then run each command of the Granular menu through
its menu action. Writes what it saw to $GRANULAR_USDVIEW_OUT/<name>.json and the
screenshots next to it.

Environment: GRANULAR_USDVIEW_OUT (folder), GRANULAR_USDVIEW_NAME (stem of the files),
GRANULAR_USDVIEW_SIZE ("W,H"), GRANULAR_USDVIEW_AGGREGATE (prim path, or empty).
"""
import json
import os
import time


def _wait(appController, limit):
    from pxr.Usdviewq.qt import QtWidgets
    t0 = time.monotonic()
    for _ in range(10):
        QtWidgets.QApplication.processEvents()
    renderer = appController._stageView._renderer
    while not renderer.IsConverged() and time.monotonic() - t0 < limit:
        QtWidgets.QApplication.processEvents()
    return renderer.IsConverged(), time.monotonic() - t0


def _granular_menu(appController):
    for action in appController._mainWindow.menuBar().actions():
        if action.text() == "Granular" and action.menu():
            return {a.text(): a for a in action.menu().actions() if a.text()}
    return {}


def testUsdviewInputFunction(appController):
    from pxr import Sdf
    from pxr.Usdviewq.qt import QtWidgets

    out, name = os.environ["GRANULAR_USDVIEW_OUT"], os.environ["GRANULAR_USDVIEW_NAME"]
    width, height = (int(v) for v in os.environ["GRANULAR_USDVIEW_SIZE"].split(","))
    aggregate = os.environ.get("GRANULAR_USDVIEW_AGGREGATE", "")
    report = {"renderer": appController._stageView.rendererDisplayName}

    # The stage's camera in a viewport of its aspect: the frustum is the camera's own, as
    # usdrecord --camera renders it. No HUD text over the image.
    settings = appController._dataModel.viewSettings
    settings.showHUD = False
    settings.domeLightTexturesVisible = True  # as usdrecord --enableDomeLightVisibility
    settings.cameraPrim = appController._dataModel.stage.GetPrimAtPath("/World/Camera")
    appController._stageView.setFixedSize(width, height)
    report["converged"], report["seconds"] = _wait(appController, 300)
    shot = os.path.join(out, name + "_hybrid.png")
    appController.GrabViewportShot().save(shot, "PNG")
    report["technique"] = str(appController._stageView.GetRendererSetting("granular:technique"))

    menu = _granular_menu(appController)
    report["menu"] = sorted(menu)
    messages = []
    # Modal dialogs would wait for a person: the test answers them.
    QtWidgets.QMessageBox.information = lambda parent, title, text, *a: messages.append(("info", title, text))
    QtWidgets.QMessageBox.warning = lambda parent, title, text, *a: messages.append(("warning", title, text))
    vdb = os.path.join(out, name + ".vdb")
    QtWidgets.QFileDialog.getSaveFileName = lambda *a, **k: (vdb, "OpenVDB (*.vdb)")
    if aggregate:
        appController._dataModel.selection.setPrimPath(Sdf.Path(aggregate))
        for _ in range(10):
            QtWidgets.QApplication.processEvents()
    # usdview rebuilds its menus as the selection changes: look each action up anew.
    for command in ("Statistics of Selected Prim", "Export Coarse Density to VDB..."):
        action = _granular_menu(appController).get(command)
        if action:
            action.trigger()
    report["messages"] = messages
    report["vdb"] = vdb if os.path.exists(vdb) else None

    # Selected prims are drawn highlighted: nothing selected for the next screenshot.
    appController._dataModel.selection.clearPrims()
    toggle = _granular_menu(appController).get("Toggle EPT-only Reference")
    if toggle:
        # The sun exact for the EPT comparison (usdview_check.py says why).
        appController._stageView.SetRendererSetting("granular:sunRegularization", 0.0)
        toggle.trigger()
        report["technique_after_toggle"] = str(appController._stageView.GetRendererSetting("granular:technique"))
        # The converged flag is the old render's until the viewport restarts the loop.
        renderer, t0 = appController._stageView._renderer, time.monotonic()
        while renderer.IsConverged() and time.monotonic() - t0 < 10:
            QtWidgets.QApplication.processEvents()
        report["ept_converged"], report["ept_seconds"] = _wait(appController, 600)
        appController.GrabViewportShot().save(os.path.join(out, name + "_ept.png"), "PNG")
    with open(os.path.join(out, name + ".json"), "w") as f:
        json.dump(report, f, indent=1)
