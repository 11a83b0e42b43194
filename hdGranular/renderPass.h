// renderPass.h — what a Hydra host executes every frame: it brings the core scene up
// to date with the least work, then lets the render loop run progressively.
//
// Contract: after an edit of the scene (meshes, lights, materials; the render param's
// version) or of the settings, the description assembled again is compared with the one
// the core scene was built from (compareScenes): a change beyond the view (lights,
// aggregates, surfaces, the technique to or from ept, the default light, the physical sun)
// builds the core scene anew, reusing every aggregate whose inputs did not change
// (Scene::build); otherwise, and for a camera move or a resize, only a new view is set (no
// re-voxelising, no re-estimation); new AOV bindings only restart the loop. The active
// UsdRenderSettings' dataWindowNDC (renderSettings.h) crops the render as in granular
// render: only its pixels are rendered, the others keep the buffers' clear values.
// A scene that cannot be built is reported once (TF_RUNTIME_ERROR naming the prim and
// attribute) and renders nothing, its buffers marked converged.
#ifndef HDGRANULAR_RENDER_PASS_H
#define HDGRANULAR_RENDER_PASS_H

#include <optional>
#include <set>
#include <string>

#include "pxr/base/gf/matrix4d.h"
#include "pxr/base/gf/vec2d.h"
#include "pxr/base/gf/vec2f.h"
#include "pxr/imaging/hd/renderPass.h"
#include "pxr/imaging/hd/renderPassState.h"
#include "pxr/pxr.h"
#include "core/scene_desc.h"

PXR_NAMESPACE_OPEN_SCOPE

class HdGranularRenderParam;
class HdGranularRenderer;

class HdGranularRenderPass final : public HdRenderPass {
 public:
  HdGranularRenderPass(HdRenderIndex* index, HdRprimCollection const& collection, HdGranularRenderParam* param,
                       HdGranularRenderer* renderer);
  ~HdGranularRenderPass() override;
  bool IsConverged() const override;

 protected:
  void _Execute(HdRenderPassStateSharedPtr const& state, TfTokenVector const& renderTags) override;

 private:
  HdGranularRenderParam* _param;
  HdGranularRenderer* _renderer;
  int _sceneVersion = -1, _settingsVersion = -1;
  // The description the core scene was built from, with its latest view (none while there
  // is no scene): what a new one is compared with (compareScenes).
  std::optional<granular::SceneDesc> _built;
  std::string _sunsWarned;  // the last widened-suns warning given
  GfMatrix4d _view{0.0}, _projection{0.0};
  GfVec2f _lens{0.0f};  // the camera's (fStop, focusDistance)
  GfVec2d _shutter{0.0};  // the shutter blurred over, in time codes (shutterOf)
  int _width = 0, _height = 0;
  granular::PixelWindow _crop;  // of the active render settings (renderSettings.h)
  HdRenderPassAovBindingVector _bindings;
  bool _started = false;
};

PXR_NAMESPACE_CLOSE_SCOPE

#endif
