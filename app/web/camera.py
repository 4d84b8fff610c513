"""Camera framing: fit boxes of the viser scene into the 3D canvas beside the panel.

The panel is docked at the right of the page (:class:`app.web.session_panel.SessionPanel`), so
the canvas is only the part of the page it leaves free (viser's floating panel covered the right
0.29 of a full-page canvas at 1400x900, and a software page drew those pixels too).
:func:`fit_camera` comes as near as it can while every corner of the boxes still projects inside
the canvas with a margin, their projected extent centred. The view direction is a view's own
(:func:`choose_direction`): of a few turned and raised views, the one that shows the device and
the world largest.

Presets (:data:`PRESETS`): both spaces, the device, the world (the scene file's ``[view]`` box if
it has one), the tool; all seen from the view's direction.

Zoom about what is under the cursor, two ways: the page's camera controls dolly toward the cursor
(:data:`DOLLY_TO_CURSOR_JS`), and a click on a mesh makes the clicked surface point the orbit
centre (:meth:`app.web.scene_view.SceneView.pick` finds it with trimesh's ray test, :func:`recentre`
moves the camera onto it).

A page whose WebGL runs in software draws its view at :data:`SOFTWARE_PIXEL_RATIO`
(:data:`SOFTWARE_RESOLUTION_JS`) and shades its lit nodes with three.js's Lambert shader
(:data:`SOFTWARE_LAMBERT_JS`), and no page draws viser's background-image quad while it has
no image (:data:`NO_EMPTY_BACKGROUND_JS`).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass

import numpy as np
import viser
from viser._messages import RunJavascriptMessage

from app.spatial import Array

#: The view directions a framing chooses among (:func:`choose_direction`): azimuths (rad) of the
#: camera round z from the front (-y; positive: from the right, so the world on the right comes
#: nearer than the device on the left) and elevations (rad) above the horizontal. The device
#: and the world stand side by side along x: seen square from the front (azimuth 0) they make a
#: wide, low band across a nearly square free view, empty above and below; turned and raised,
#: their x gap shortens and their depths spread up the view.
AZIMUTHS = np.radians(np.arange(0.0, 46.0, 5.0))
ELEVATIONS = np.radians(np.arange(20.0, 46.0, 5.0))
#: Vertical field of view set on every browser (rad).
FOV = math.radians(45.0)
#: Width of the panel docked at the right of the page (CSS px): viser 1.1's "large" panel's
#: (measured in chromium at 1400x900: the canvas beside it is 1008 px wide, the dock's edge 4). Set explicitly: a
#: page that docked the panel before it took the theme's width kept a narrower one (325 px).
PANEL_WIDTH = 388
#: Share of the width and of the height left empty on each side of the framed box.
MARGIN = 0.06
#: The presets offered in the panel.
PRESETS = ("both", "device", "world", "tool")


@dataclass(frozen=True)
class CameraPose:
    """Where a camera is and what it looks at (viser frame, m)."""

    position: Array
    look_at: Array


def view_direction(azimuth: float, elevation: float) -> Array:
    """Unit vector (3,) from the camera toward the scene (viser frame, z up) for a camera at
    ``azimuth`` (rad, round z from the front, -y; positive toward +x) and ``elevation`` (rad)
    above the horizontal."""
    c = math.cos(elevation)
    return np.array([-math.sin(azimuth) * c, math.cos(azimuth) * c, -math.sin(elevation)])


def _basis(forward: Array) -> tuple[Array, Array, Array]:
    """Camera right, up and forward unit vectors looking along ``forward`` (z up)."""
    right = np.cross(forward, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    return right, np.cross(right, forward), forward


def box_corners(box: Array) -> Array:
    """The 8 corners (8, 3) of an axis-aligned box ``[min, max]`` (2, 3)."""
    return np.array([[box[i, 0], box[j, 1], box[k, 2]] for i in (0, 1) for j in (0, 1) for k in (0, 1)])


def project(points: Array, pose: CameraPose, fov: float, width: float, height: float) -> Array:
    """Pixel coordinates (k, 2) of ``points`` (k, 3) in a ``width`` x ``height`` canvas (x right,
    y down from the top-left) seen from ``pose`` with vertical field of view ``fov`` (rad), z up."""
    forward = pose.look_at - pose.position
    forward = forward / np.linalg.norm(forward)
    right = np.cross(forward, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    up = np.cross(right, forward)
    rel = points - pose.position
    depth = rel @ forward
    t = math.tan(fov / 2)
    x_ndc = (rel @ right) / (depth * t * width / height)
    y_ndc = (rel @ up) / (depth * t)
    return np.stack(((x_ndc + 1) * width / 2, (1 - y_ndc) * height / 2), axis=1)


def fit_camera(points: Array, aspect: float, forward: Array, fov: float = FOV) -> CameraPose:
    """The camera looking along ``forward`` (unit, (3,)) nearest to ``points`` ((k, 3), viser
    frame, m) that still shows every point in the canvas (width / height ``aspect``),
    :data:`MARGIN` clear of each edge: the points as large as they fit, their projected extent
    centred.

    At a distance ``d`` the camera may still slide sideways (``s_x`` along the camera's right,
    ``s_y`` along its up); each point bounds each slide on both sides linearly, so ``d`` fits if
    both slides' bounds leave room. The least such ``d`` is found by bisection; the slides are
    then the middles of their (then nearly closed) ranges."""
    right, up, forward = _basis(forward)
    centre = 0.5 * (points.min(axis=0) + points.max(axis=0))
    q = points - centre
    t = math.tan(fov / 2)
    half = 1 - MARGIN  # NDC half-extent the points may reach, x and y
    qr, qu, qf = q @ right, q @ up, q @ forward

    def slides(distance: float) -> tuple[float, float, float, float] | None:
        """Each slide's range ``(lo_x, hi_x, lo_y, hi_y)`` (m) at ``distance``, None if empty:
        a point's NDC x is ``(q.right - s_x) / (depth t aspect)``, and likewise y."""
        depth = distance + qf
        if np.any(depth <= 0):
            return None
        dx, dy = depth * t * aspect, depth * t
        lo_x, hi_x = np.max(qr - half * dx), np.min(qr + half * dx)
        lo_y, hi_y = np.max(qu - half * dy), np.min(qu + half * dy)
        if lo_x > hi_x or lo_y > hi_y:
            return None
        return float(lo_x), float(hi_x), float(lo_y), float(hi_y)

    near, far = 1e-3, 1.0
    while slides(far) is None:
        near, far = far, 2 * far
    for _ in range(40):  # bisection to 1e-12 of the bracket: exact enough for pixels
        mid = 0.5 * (near + far)
        near, far = (near, mid) if slides(mid) is not None else (mid, far)
    fitted = slides(far)
    assert fitted is not None
    lo_x, hi_x, lo_y, hi_y = fitted
    look_at = centre + 0.5 * (lo_x + hi_x) * right + 0.5 * (lo_y + hi_y) * up
    return CameraPose(position=look_at - far * forward, look_at=look_at)


def canvas_share(points: Array, pose: CameraPose, fov: float, aspect: float) -> float:
    """Share of the canvas (width / height ``aspect``) that the rectangle round ``points``
    ((k, 3), viser frame), seen from ``pose``, covers (clipped to the canvas)."""
    px = project(points, pose, fov, aspect, 1.0)
    lo = np.clip(px.min(axis=0), 0.0, [aspect, 1.0])
    hi = np.clip(px.max(axis=0), 0.0, [aspect, 1.0])
    return float(np.prod(hi - lo) / aspect)


def choose_direction(points: Array, aspect: float, fov: float = FOV) -> Array:
    """The view direction (unit, (3,)) among :data:`AZIMUTHS` x :data:`ELEVATIONS` whose fitted
    camera (:func:`fit_camera`) shows the rectangle round ``points`` ((k, 3), viser frame)
    largest in the canvas (:func:`canvas_share`); ties go to the first, the lowest azimuth and
    elevation."""
    best, best_share = view_direction(AZIMUTHS[0], ELEVATIONS[0]), -1.0
    for azimuth in AZIMUTHS:
        for elevation in ELEVATIONS:
            forward = view_direction(azimuth, elevation)
            share = canvas_share(points, fit_camera(points, aspect, forward, fov), fov, aspect)
            if share > best_share + 1e-9:
                best, best_share = forward, share
    return best


def recentre(pose: CameraPose, point: Array) -> CameraPose:
    """``pose`` moved (not turned) so that it looks at ``point`` (viser frame, m) from the same
    direction and distance: the point clicked becomes the centre the view orbits and zooms about."""
    return CameraPose(position=point + (pose.position - pose.look_at), look_at=np.asarray(point, dtype=float))


#: Run in each page: its camera controls (camera-controls, which viser 1.1.1 drives) dolly toward
#: the point under the cursor instead of the orbit centre. viser offers no call for this; the page
#: keeps its controls at ``window.__viserMutable.cameraControl`` (viser's hook for its own browser
#: tests). Checked every half second: the controls exist only once the canvas is mounted, and a
#: remount makes new ones.
DOLLY_TO_CURSOR_JS = """(() => {
  const apply = () => {
    const controls = window.__viserMutable && window.__viserMutable.cameraControl;
    if (controls && !controls.dollyToCursor) controls.dollyToCursor = true;
  };
  apply();
  setInterval(apply, 500);
})();"""


#: Device pixels per CSS pixel of the 3D view in a page whose WebGL runs in software (no GPU).
#: Each frame there costs the browser's GPU process CPU time roughly in proportion to the
#: canvas' pixels beyond a fixed part: while dragging (1400x900 page, one run each, load 5-6)
#: 45 ms a frame at viser's own adaptive floor of 0.75 (1050x675), 30-34 ms at 0.5, 25-27 ms at
#: 0.25; the view then drew 17-23 frames/s against 11-16. 0.5 keeps the labels legible.
SOFTWARE_PIXEL_RATIO = 0.5

#: A JavaScript function of ``HTMLCanvasElement.prototype.getContext`` (passed in, so that a
#: script wrapping it can call the original): whether the page's WebGL renderer is a software
#: one, by the names viser's own "software WebGL" notice looks for (a throwaway context is made,
#: asked and let go).
SOFTWARE_WEBGL = """(getContext) => {
  const probe = getContext.call(document.createElement('canvas'), 'webgl');
  const info = probe && probe.getExtension('WEBGL_debug_renderer_info');
  const renderer = info ? String(probe.getParameter(info.UNMASKED_RENDERER_WEBGL)).toLowerCase() : '';
  const lose = probe && probe.getExtension('WEBGL_lose_context');
  if (lose) lose.loseContext();
  return ['swiftshader', 'llvmpipe', 'software'].some((name) => renderer.includes(name));
}"""

#: Run in each page: if its WebGL renderer is a software one (the names viser's own "software
#: WebGL" notice looks for), draw the view at :data:`SOFTWARE_PIXEL_RATIO`, through viser's
#: ``fixedDpr`` setting (its URL parameter; set here through ``window.__viserTestpoints``, viser's
#: hook for its own browser tests). A page opened with ``?fixedDpr=`` keeps the visitor's choice;
#: with a GPU, viser's adaptive pixel ratio stays in charge.
SOFTWARE_RESOLUTION_JS = """(() => {
  if (new URLSearchParams(window.location.search).has('fixedDpr')) return;
  if (!(SOFTWARE_WEBGL)(HTMLCanvasElement.prototype.getContext)) return;
  const apply = () => {
    const points = window.__viserTestpoints;
    if (!points || !points.devSettings) return false;
    points.devSettings.set({ fixedDpr: SOFTWARE_PIXEL_RATIO });
    return true;
  };
  if (!apply()) {
    const timer = setInterval(() => { if (apply()) clearInterval(timer); }, 200);
  }
})();""".replace("SOFTWARE_PIXEL_RATIO", str(SOFTWARE_PIXEL_RATIO)).replace("SOFTWARE_WEBGL", SOFTWARE_WEBGL)

#: Run first in each page, before viser's script makes its WebGL context: a page whose WebGL runs
#: in software makes that context without antialiasing (multisampling). In software each sample
#: is rasterized and resolved on the CPU: while dragging (1400x900 page at
#: :data:`SOFTWARE_PIXEL_RATIO`, load 6-9, pages alternated, two 4 s windows each) the GPU
#: process spent 17.9-24.8 ms of CPU a 3D frame in two pages against 26.5-37.1 in three with
#: antialiasing (and the bench's five pairs: ``README.md``). The view's edges are then
#: stair-stepped; the labels read as before (screenshots of both at this ratio). As with
#: :data:`SOFTWARE_RESOLUTION_JS`, a page opened with ``?fixedDpr=`` is left as viser makes it.
#: Served in the page's ``<head>`` (:func:`app.web.launch.script_in_page_head`): a context's
#: antialiasing is fixed when it is made, before any message reaches the page.
SOFTWARE_NO_ANTIALIAS_JS = """(() => {
  if (new URLSearchParams(window.location.search).has('fixedDpr')) return;
  const getContext = HTMLCanvasElement.prototype.getContext;
  let software = null;
  HTMLCanvasElement.prototype.getContext = function (kind, attributes) {
    if (kind === 'webgl2' || kind === 'webgl') {
      if (software === null) software = (SOFTWARE_WEBGL)(getContext);
      if (software) attributes = Object.assign({}, attributes, { antialias: false });
    }
    return getContext.call(this, kind, attributes);
  };
})();""".replace("SOFTWARE_WEBGL", SOFTWARE_WEBGL)


#: three.js r186's Lambert fragment shader (``meshlambert.glsl.js``, as viser 1.1.1's page
#: bundles it), given to viser's lit nodes in a page without a GPU (:data:`SOFTWARE_LAMBERT_JS`).
#: Its chunks are three.js's own, resolved by three.js when it compiles the program; the standard
#: material's own ``STANDARD`` define, which three.js puts before it, is taken back (with it the
#: light chunks read the physical material's fields).
LAMBERT_FRAGMENT = """
#undef STANDARD
#define LAMBERT
uniform vec3 diffuse;
uniform vec3 emissive;
uniform float opacity;
#include <common>
#include <dithering_pars_fragment>
#include <color_pars_fragment>
#include <uv_pars_fragment>
#include <map_pars_fragment>
#include <alphamap_pars_fragment>
#include <alphatest_pars_fragment>
#include <alphahash_pars_fragment>
#include <aomap_pars_fragment>
#include <lightmap_pars_fragment>
#include <emissivemap_pars_fragment>
#include <envmap_common_pars_fragment>
#include <envmap_pars_fragment>
#include <fog_pars_fragment>
#include <bsdfs>
#include <lights_pars_begin>
#include <normal_pars_fragment>
#include <lights_lambert_pars_fragment>
#include <shadowmap_pars_fragment>
#include <bumpmap_pars_fragment>
#include <normalmap_pars_fragment>
#include <specularmap_pars_fragment>
#include <logdepthbuf_pars_fragment>
#include <clipping_planes_pars_fragment>
void main() {
  vec4 diffuseColor = vec4( diffuse, opacity );
  #include <clipping_planes_fragment>
  ReflectedLight reflectedLight = ReflectedLight( vec3( 0.0 ), vec3( 0.0 ), vec3( 0.0 ), vec3( 0.0 ) );
  vec3 totalEmissiveRadiance = emissive;
  #include <logdepthbuf_fragment>
  #include <map_fragment>
  #include <color_fragment>
  #include <alphamap_fragment>
  #include <alphatest_fragment>
  #include <alphahash_fragment>
  #include <specularmap_fragment>
  #include <normal_fragment_begin>
  #include <normal_fragment_maps>
  #include <emissivemap_fragment>
  #include <lights_lambert_fragment>
  #include <lights_fragment_begin>
  #include <lights_fragment_maps>
  #include <lights_fragment_end>
  #include <aomap_fragment>
  vec3 outgoingLight = reflectedLight.directDiffuse + reflectedLight.indirectDiffuse + totalEmissiveRadiance;
  #include <envmap_fragment>
  #include <opaque_fragment>
  #include <tonemapping_fragment>
  #include <colorspace_fragment>
  #include <fog_fragment>
  #include <premultiplied_alpha_fragment>
  #include <dithering_fragment>
}
"""

#: Run in each page: if its WebGL renderer is a software one, viser's lit nodes (the device's
#: links, the world's objects, the tool, the wrench arrows: ``MeshStandardMaterial``, the only lit
#: material viser 1.1.1 offers besides toon shading) are shaded by three.js's Lambert shader
#: (:data:`LAMBERT_FRAGMENT`) instead of its physically based one. viser's standard material has
#: roughness 1 and metalness 0 and the demo sets no environment map, so the two shade the same
#: diffuse light and differ by the faint broad specular term only; in software each lit draw's
#: fragments are shaded on the CPU. Done through three.js's ``onBeforeCompile`` hook (and a
#: program cache key of its own), set on each lit material, which is then compiled again once;
#: checked every half second, as nodes come and go with the scene (a new node may be drawn
#: physically based for that long). Set on each material, not on the class: viser's batched
#: nodes (``InstancedMesh2``) wrap a material's own hook at each draw and leave it on the
#: material as its own property, which hides one set on the class. As with :data:`SOFTWARE_RESOLUTION_JS`, a page opened with ``?fixedDpr=``
#: is left as viser makes it.
SOFTWARE_LAMBERT_JS = """(() => {
  if (new URLSearchParams(window.location.search).has('fixedDpr')) return;
  if (!(SOFTWARE_WEBGL)(HTMLCanvasElement.prototype.getContext)) return;
  const fragment = LAMBERT_FRAGMENT;
  const lambert = (shader) => { shader.fragmentShader = fragment; };
  const key = () => 'lambert';
  const apply = () => {
    const mutable = window.__viserMutable;
    if (!mutable || !mutable.scene) return;
    mutable.scene.traverse((o) => {
      for (const m of Array.isArray(o.material) ? o.material : [o.material]) {
        if (m && m.type === 'MeshStandardMaterial' && m.onBeforeCompile !== lambert) {
          m.onBeforeCompile = lambert;
          m.customProgramCacheKey = key;
          m.needsUpdate = true;
        }
      }
    });
  };
  apply();
  setInterval(apply, 500);
})();""".replace("SOFTWARE_WEBGL", SOFTWARE_WEBGL).replace("LAMBERT_FRAGMENT", json.dumps(LAMBERT_FRAGMENT))


#: Run in each page: hide viser's background-image quad while no background image is set. viser
#: 1.1.1 draws that quad over the whole canvas every frame, and with no image its fragment shader
#: discards every pixel: nothing shows, but in software WebGL it is a full-canvas shading pass
#: (dragging, 1400x900, three alternated rounds at load 7-8: 31-33 against 25-26 ms of the GPU
#: process's CPU a 3D frame). The page keeps the quad's material at
#: ``window.__viserMutable.backgroundMaterial``; the quad is shown again, within half a second,
#: if an image is set (the demo sets none). Checked every half second, as a remounted canvas
#: makes a new quad.
NO_EMPTY_BACKGROUND_JS = """(() => {
  const apply = () => {
    const mutable = window.__viserMutable;
    const material = mutable && mutable.backgroundMaterial;
    if (!material || !mutable.scene) return;
    const shown = Boolean(material.uniforms.enabled.value);
    mutable.scene.traverse((o) => { if (o.material === material && o.visible !== shown) o.visible = shown; });
  };
  apply();
  setInterval(apply, 500);
})();"""


def run_in_page(client: viser.ClientHandle, source: str) -> None:
    """Run the script ``source`` in ``client``'s page (:data:`DOLLY_TO_CURSOR_JS`,
    :data:`SOFTWARE_RESOLUTION_JS`, :data:`SOFTWARE_LAMBERT_JS`, :data:`NO_EMPTY_BACKGROUND_JS`), through the message viser itself uses to run script in a
    page (viser 1.1.1 has no public call for it)."""
    client._websock_connection.queue_message(RunJavascriptMessage(source=source))
