// The camera views: the two-link bench's spot camera (a zoom around the spot, the full frame
// on click) and, on an arm run, every tool camera's latest frame with the markers it saw;
// and the bring-up preview of the daemon's devices while idle.
import { API, apiError, authHeaders, fail, say } from "./api.js";
import { $, element, num } from "./util.js";

// The stream's thumbnail is the frame reduced by `scale` (each pixel the brightest of a
// scale x scale block). A small spot on a dark frame is lost at that size, so the view
// shows a crop around the centroid, enlarged and contrast-stretched over the crop alone;
// a click switches to the whole frame (with the crop outlined) and back.
const CROP_PX = 16; // thumbnail pixels each side of the crop (16 x 4 = 64 frame pixels)
const ZOOM_CANVAS_PX = 256;
const frameView = { image: null, crop: null, frame: null, full: false };

function loadImage(base64) {
  return new Promise((resolve, reject) => {
    const image = new Image();
    image.onload = () => resolve(image);
    image.onerror = reject;
    image.src = `data:image/png;base64,${base64}`;
  });
}

export async function showFrame(frame) {
  if (frame.camera) {
    showToolCamera(frame);
    return;
  }
  // the thumbnail, and (when the spot was found) the server's full-resolution crop around it
  const [image, crop] = await Promise.all([loadImage(frame.png_base64),
    frame.crop_png_base64 ? loadImage(frame.crop_png_base64) : Promise.resolve(null)]);
  Object.assign(frameView, { image, crop, frame });
  drawFrame();
}

function cross(context, cx, cy, gap, arm, colour = "#ff3b30") {
  // a cross with a gap in the middle, so the spot itself stays visible
  context.strokeStyle = colour;
  context.lineWidth = 1.5;
  context.beginPath();
  for (const [dx, dy] of [[1, 0], [-1, 0], [0, 1], [0, -1]]) {
    context.moveTo(cx + gap * dx, cy + gap * dy);
    context.lineTo(cx + arm * dx, cy + arm * dy);
  }
  context.stroke();
}

function drawCrop(canvas, context, frame, crop, x, y) {
  // the server's crop: full resolution, already contrast-stretched over the crop itself
  const size = Number(frame.crop_size_px);
  canvas.width = ZOOM_CANVAS_PX;
  canvas.height = ZOOM_CANVAS_PX;
  context.imageSmoothingEnabled = false;
  context.drawImage(crop, 0, 0, ZOOM_CANVAS_PX, ZOOM_CANVAS_PX);
  const zoom = ZOOM_CANVAS_PX / size;
  // frame pixel centres are at integers: pixel c spans c - 0.5 .. c + 0.5
  const cx = (x - Number(frame.crop_x0_px) + 0.5) * zoom;
  const cy = (y - Number(frame.crop_y0_px) + 0.5) * zoom;
  cross(context, cx, cy, 1.5 * zoom, 5 * zoom);
  canvas.dataset.view = "zoom";
  canvas.dataset.contrast = `${Math.round(frame.crop_low)}-${Math.round(frame.crop_high)}`;
  $("frame-detail").textContent = `zoom around the spot: ${size} x ${size} frame px at full `
    + "resolution, contrast stretched over the crop; click for the full frame";
}

function cropOrigin(frame, cx, cy) {
  const clamp = (v, size) => Math.max(0, Math.min(Math.round(v - CROP_PX / 2), size - CROP_PX));
  return [clamp(cx, frame.width), clamp(cy, frame.height)];
}

function drawFrame() {
  const { image, frame } = frameView;
  if (!image || !frame) return;
  const canvas = $("frame-canvas");
  const context = canvas.getContext("2d");
  const x = num(frame.centroid_x_px);
  const y = num(frame.centroid_y_px);
  const scale = Number(frame.scale) || 1;
  // frame pixel centres are at integers; thumbnail pixel (r, c) covers scale x scale pixels
  const cx = x === null ? null : (x + 0.5) / scale;
  const cy = y === null ? null : (y + 0.5) / scale;
  const where = x === null ? "no centroid" : `centroid (${x.toFixed(2)}, ${y.toFixed(2)}) px`;
  $("frame-caption").textContent = `run ${frame.run_id} step ${frame.step}: ${where}`;
  const small = frame.width < CROP_PX || frame.height < CROP_PX;
  if (frameView.full || cx === null || small) {
    canvas.width = frame.width;
    canvas.height = frame.height;
    context.imageSmoothingEnabled = false;
    context.drawImage(image, 0, 0);
    if (cx !== null) {
      cross(context, cx, cy, 4, 12);
      if (!small) {
        const [sx, sy] = cropOrigin(frame, cx, cy);
        context.strokeStyle = "#ffd60a";
        context.lineWidth = 1;
        context.strokeRect(sx + 0.5, sy + 0.5, CROP_PX - 1, CROP_PX - 1);
      }
    }
    canvas.dataset.view = "full";
    $("frame-detail").textContent = `full frame, reduced 1:${scale} (${frame.width} x `
      + `${frame.height} px)${cx === null ? "" : "; yellow: the zoomed area; click to zoom"}`;
    return;
  }
  if (frameView.crop) {
    drawCrop(canvas, context, frame, frameView.crop, x, y);
    return;
  }
  const [sx, sy] = cropOrigin(frame, cx, cy);
  const scratch = document.createElement("canvas");
  scratch.width = CROP_PX;
  scratch.height = CROP_PX;
  const crop = scratch.getContext("2d");
  crop.drawImage(image, sx, sy, CROP_PX, CROP_PX, 0, 0, CROP_PX, CROP_PX);
  const pixels = crop.getImageData(0, 0, CROP_PX, CROP_PX);
  let low = 255;
  let high = 0;
  for (let i = 0; i < pixels.data.length; i += 4) {
    low = Math.min(low, pixels.data[i]);
    high = Math.max(high, pixels.data[i]);
  }
  const span = Math.max(high - low, 1);
  for (let i = 0; i < pixels.data.length; i += 4) {
    const v = Math.round(((pixels.data[i] - low) * 255) / span);
    pixels.data[i] = v;
    pixels.data[i + 1] = v;
    pixels.data[i + 2] = v;
  }
  crop.putImageData(pixels, 0, 0);
  canvas.width = ZOOM_CANVAS_PX;
  canvas.height = ZOOM_CANVAS_PX;
  context.imageSmoothingEnabled = false;
  context.drawImage(scratch, 0, 0, ZOOM_CANVAS_PX, ZOOM_CANVAS_PX);
  const zoom = ZOOM_CANVAS_PX / CROP_PX;
  cross(context, (cx - sx) * zoom, (cy - sy) * zoom, 2 * zoom, 6 * zoom);
  canvas.dataset.view = "zoom";
  canvas.dataset.contrast = `${low}-${high}`;
  $("frame-detail").textContent = `zoom around the spot: ${CROP_PX * scale} x ${CROP_PX * scale}`
    + " frame px, contrast stretched over the crop; click for the full frame";
}

$("frame-canvas").addEventListener("click", () => {
  frameView.full = !frameView.full;
  drawFrame();
});

// --- the arm's tool cameras: one tile per camera, its markers crossed ------------------

async function showToolCamera(frame) {
  const grid = $("camera-grid");
  let tile = grid.querySelector(`[data-camera="${CSS.escape(frame.camera)}"]`);
  if (!tile) {
    tile = element("figure", "camera-tile");
    tile.dataset.camera = frame.camera;
    tile.append(element("canvas"), element("figcaption"));
    grid.append(tile);
    [...grid.children].sort((a, b) => a.dataset.camera.localeCompare(b.dataset.camera))
      .forEach((child) => grid.append(child));
  }
  const markers = Array.isArray(frame.markers_px) ? frame.markers_px : [];
  // a camera that watches another pose sees no marker at this one: its tile keeps the last
  // frame in which it saw the tool
  if (!markers.length && Number(tile.dataset.markers) > 0 && tile.dataset.pose !== frame.pose) {
    return;
  }
  const image = await loadImage(frame.png_base64);
  const canvas = tile.querySelector("canvas");
  canvas.width = frame.width;
  canvas.height = frame.height;
  const context = canvas.getContext("2d");
  context.drawImage(image, 0, 0);
  const scale = Number(frame.scale) || 1;
  for (const [mx, my] of markers) {
    cross(context, (mx + 0.5) / scale, (my + 0.5) / scale, 2, 7, "#ffd60a");
  }
  const pose = frame.pose ? ` at ${frame.pose}` : "";
  tile.querySelector("figcaption").textContent =
    `${frame.camera}${pose} (step ${frame.step}): ${markers.length} marker`
    + `${markers.length === 1 ? "" : "s"} seen`;
  tile.dataset.markers = String(markers.length);
  tile.dataset.pose = frame.pose || "";
  $("frame-caption").textContent = `run ${frame.run_id} step ${frame.step}: the tool cameras`;
  $("frame-detail").textContent = "each camera's latest frame (brightest pixel per block, "
    + "contrast stretched); yellow crosses: the markers it measured";
}

export function clearCameras() {
  $("camera-grid").replaceChildren();
}

// --- the bring-up preview (issue 18): a PNG, fetched with the token like every read ----

export async function preview() {
  try {
    const response = await fetch(`${API}/devices/preview`, { headers: authHeaders() });
    if (!response.ok) {
      const text = await response.text();
      let data = null;
      try { data = JSON.parse(text); } catch { data = { message: text }; }
      throw apiError(response, data);
    }
    const image = $("preview-image");
    if (image.src) URL.revokeObjectURL(image.src);
    image.src = URL.createObjectURL(await response.blob());
    image.hidden = false;
    const dialog = $("preview-dialog");
    if (!dialog.open) dialog.showModal();
    const spot = response.headers.get("X-Thermocomp-Spot-Px");
    const cameras = response.headers.get("X-Thermocomp-Cameras");
    const errors = response.headers.get("X-Thermocomp-Device-Errors");
    const found = cameras ? `tool cameras: ${cameras}` : (spot ? `spot at (${spot}) px`
      : "no spot found");
    const caption = found + (errors ? `; device errors: ${errors}` : "");
    $("preview-caption").textContent = caption;
    $("preview-dialog-caption").textContent = caption;
    say(cameras ? "preview: every tool camera, one IR image and the robot pose"
      : "preview: one frame, one IR image and the robot pose");
  } catch (error) {
    fail(error, "preview refused");
  }
}
