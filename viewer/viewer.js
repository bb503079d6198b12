// The crpgs viewer page. `crpgs view` serves it with scene.json:
//   { "title", "splat": URL of the .ply, "background": [r, g, b] (0..1),
//     "cameras": [{ "name", "width", "height", "fx", "fy", "cx", "cy",
//                   "c2w": 16 numbers, column-major, camera-to-world in THREE's convention
//                          (x right, y up, looking down -z) }] }
// Interactive by default: orbit/pan/zoom, ←/→ step through the dataset's cameras.
// `?camera=K` draws camera K exactly (its size, focal lengths and principal point; no
// controls): what the tests compare with crpgs's own render. window.crpgsViewer.ready turns
// true once the splats are loaded and drawn.
import * as THREE from "three";
import { OrbitControls } from "three/addons/controls/OrbitControls.js";
import { SparkRenderer, SplatMesh } from "@sparkjsdev/spark";

const state = { ready: false, camera: -1, splats: 0, error: null };
window.crpgsViewer = state;
const hud = document.getElementById("hud");

function fail(message) {
  state.error = message;
  hud.textContent = "error: " + message;
  throw new Error(message);
}

const info = await fetch("scene.json").then((r) => (r.ok ? r.json() : fail("scene.json: " + r.status)));
const cameras = info.cameras || [];
const query = new URLSearchParams(location.search);
const exact = query.has("camera");
let index = exact ? Number(query.get("camera")) : 0;
if (exact && !(Number.isInteger(index) && index >= 0 && index < cameras.length))
  fail(`camera ${query.get("camera")} is not one of the ${cameras.length} cameras`);

// The renderer draws as crpgs's rasterizer does: 3DGS's 0.3 px² dilation without opacity
// compensation (preBlurAmount, not blurAmount), no antialiasing of its own, 1 pixel per pixel
// in exact mode.
const renderer = new THREE.WebGLRenderer({ antialias: false, preserveDrawingBuffer: true });
renderer.setPixelRatio(exact ? 1 : window.devicePixelRatio);
const bg = info.background || [0, 0, 0];
renderer.setClearColor(new THREE.Color().setRGB(bg[0], bg[1], bg[2], THREE.SRGBColorSpace), 1);
document.body.appendChild(renderer.domElement);

const scene = new THREE.Scene();
scene.add(new SparkRenderer({ renderer, preBlurAmount: 0.3, blurAmount: 0.0 }));
const splats = new SplatMesh({ url: info.splat });
scene.add(splats);

const camera = new THREE.PerspectiveCamera();
camera.near = 0.01;
camera.far = 1000;
const controls = exact ? null : new OrbitControls(camera, renderer.domElement);

// OpenGL projection of a pinhole camera (focal lengths and principal point in pixels): keeps
// an off-centre principal point, which PerspectiveCamera's field of view cannot.
function setProjection(fx, fy, cx, cy, width, height) {
  const n = camera.near, f = camera.far;
  camera.projectionMatrix.set(
    (2 * fx) / width, 0, 1 - (2 * cx) / width, 0,
    0, (2 * fy) / height, (2 * cy) / height - 1, 0,
    0, 0, -(f + n) / (f - n), (-2 * f * n) / (f - n),
    0, 0, -1, 0);
  camera.projectionMatrixInverse.copy(camera.projectionMatrix).invert();
}

function resize() {
  const c = cameras[index];
  if (exact) {
    renderer.setSize(c.width, c.height);
    setProjection(c.fx, c.fy, c.cx, c.cy, c.width, c.height);
    return;
  }
  const w = window.innerWidth, h = window.innerHeight;
  renderer.setSize(w, h);
  // The dataset camera's vertical field of view, centred.
  const f = c ? (c.fy * h) / c.height : h;
  setProjection(f, f, w / 2, h / 2, w, h);
}

// Orbits about the point the camera looks at, as far away as the scene's centre.
function lookFrom(i) {
  index = (i + cameras.length) % cameras.length;
  state.camera = index;
  const c = cameras[index];
  new THREE.Matrix4().fromArray(c.c2w).decompose(camera.position, camera.quaternion, new THREE.Vector3());
  camera.updateMatrixWorld(true);
  resize();
  if (controls) {
    const forward = new THREE.Vector3(0, 0, -1).applyQuaternion(camera.quaternion);
    const centre = splats.isInitialized ? splats.getBoundingBox(true).getCenter(new THREE.Vector3()) : null;
    const depth = centre ? Math.max(centre.sub(camera.position).dot(forward), 0.1) : 1;
    controls.target.copy(camera.position).addScaledVector(forward, depth);
    controls.update();
  }
  showHud();
}

function showHud() {
  const where = cameras.length ? `camera ${index + 1}/${cameras.length} ${cameras[index].name}` : "no cameras";
  hud.hidden = exact;
  hud.textContent = `${info.title || ""} · ${state.splats} Gaussians · ${where}` +
    (exact ? "" : (cameras.length ? " · ←/→ cameras" : "") + " · drag orbit, right-drag pan, wheel zoom");
}

if (controls && cameras.length) {
  // Every camera's up, averaged: the scene's up for orbits and forward-facing captures alike.
  const up = new THREE.Vector3();
  for (const c of cameras) up.add(new THREE.Vector3().setFromMatrixColumn(new THREE.Matrix4().fromArray(c.c2w), 1));
  if (up.lengthSq() > 1e-12) camera.up.copy(up.normalize());
}
window.addEventListener("resize", resize);
window.addEventListener("keydown", (e) => {
  if (!cameras.length || exact) return;
  if (e.key === "ArrowRight" || e.key === "PageDown") lookFrom(index + 1);
  if (e.key === "ArrowLeft" || e.key === "PageUp") lookFrom(index - 1);
});

if (cameras.length) {
  lookFrom(index);
} else {
  resize();
}
try {
  await splats.initialized;
} catch (e) {
  fail(`${info.splat}: ${e}`);
}
state.splats = splats.numSplats ?? 0;
if (cameras.length) {
  lookFrom(index);
} else {
  // No cameras: look at the scene's bounding box from its +z side.
  const box = splats.getBoundingBox(true);
  const centre = box.getCenter(new THREE.Vector3());
  const radius = box.getSize(new THREE.Vector3()).length() / 2 || 1;
  camera.position.copy(centre).add(new THREE.Vector3(0, 0, 2.5 * radius));
  controls.target.copy(centre);
  controls.update();
  showHud();
}

// Spark sorts the splats for a view in a worker: a view is final a few frames after it is set.
let frames = 0;
renderer.setAnimationLoop(() => {
  if (controls) controls.update();
  renderer.render(scene, camera);
  if (++frames === 30) state.ready = true;
});
