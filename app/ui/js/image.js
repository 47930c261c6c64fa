// sensor_msgs/msg/Image drawn on a canvas, from the ?bytes=base64 form of the message.
//
// Encodings: rgb8, bgr8, rgba8, bgra8, mono8 (and mono16 / 16UC1, scaled to 8 bits).  Rows are
// read with the message's own `step` (rows may be padded).  The canvas has the image's own size
// and CSS scales it up; its ImageData is reused while the size stays the same.

const CHANNELS = { rgb8: 3, bgr8: 3, rgba8: 4, bgra8: 4, mono8: 1, "8UC1": 1, "8UC3": 3, mono16: 2, "16UC1": 2 };
export const IMAGE_TYPE = "sensor_msgs/msg/Image";

function bytesOf(data) {
  if (typeof data === "string") {
    if (Uint8Array.fromBase64) return Uint8Array.fromBase64(data);
    const text = atob(data);
    const out = new Uint8Array(text.length);
    for (let i = 0; i < text.length; i += 1) out[i] = text.charCodeAt(i);
    return out;
  }
  if (Array.isArray(data)) return Uint8Array.from(data);
  throw new Error("the image has no data");
}

export class ImageCanvas {
  constructor(canvas) {
    this.canvas = canvas;
    this.ctx = canvas.getContext("2d");
    this.pixels = null;
  }

  /** Draw one message; throws an Error that says why it cannot be drawn. */
  draw(msg) {
    const { width, height, step, encoding } = msg;
    const channels = CHANNELS[encoding];
    if (!channels) throw new Error(`encoding ${JSON.stringify(encoding)} is not drawn (rgb8, bgr8, rgba8, bgra8, mono8, mono16)`);
    if (!(width > 0 && height > 0)) throw new Error("the image is empty");
    if (!(step >= width * channels)) throw new Error(`step ${step} is smaller than width × ${channels}`);
    const src = bytesOf(msg.data);
    if (src.length < step * (height - 1) + width * channels) {
      throw new Error(`the image has ${src.length} bytes of data, less than step × height`);
    }
    if (this.canvas.width !== width || this.canvas.height !== height || !this.pixels) {
      this.canvas.width = width;
      this.canvas.height = height;
      this.pixels = this.ctx.createImageData(width, height);
    }
    const out = this.pixels.data;
    const bigEndian = Boolean(msg.is_bigendian);
    for (let y = 0; y < height; y += 1) {
      let s = y * step;
      let d = y * width * 4;
      for (let x = 0; x < width; x += 1, d += 4) {
        let r;
        let g;
        let b;
        let a = 255;
        switch (encoding) {
          case "rgb8": case "8UC3":
            r = src[s]; g = src[s + 1]; b = src[s + 2]; s += 3; break;
          case "bgr8":
            b = src[s]; g = src[s + 1]; r = src[s + 2]; s += 3; break;
          case "rgba8":
            r = src[s]; g = src[s + 1]; b = src[s + 2]; a = src[s + 3]; s += 4; break;
          case "bgra8":
            b = src[s]; g = src[s + 1]; r = src[s + 2]; a = src[s + 3]; s += 4; break;
          case "mono16": case "16UC1":
            r = g = b = bigEndian ? src[s] : src[s + 1]; s += 2; break;
          default:
            r = g = b = src[s]; s += 1;
        }
        out[d] = r; out[d + 1] = g; out[d + 2] = b; out[d + 3] = a;
      }
    }
    this.ctx.putImageData(this.pixels, 0, 0);
    this.canvas.dataset.drawn = String(Number(this.canvas.dataset.drawn || 0) + 1);
  }
}
