#version 330
// A view's depth at chosen pixels, read on the GPU (transform feedback, no rasterising): a
// point per pixel, its value captured as `value`. Box visibility asks for a few thousand of a
// camera's 1.4 million pixels, and the whole depth image read back had cost a GPU shared by
// sixteen workers a sixth of its frames (docs/benchmarks.md).
// Uniforms: image (the view's depth attachment, one float a texel; row 0 the image's top).
uniform sampler2D image;
in ivec2 texel;  // column, row
out float value;
void main() {
    value = texelFetch(image, texel, 0).r;
}
