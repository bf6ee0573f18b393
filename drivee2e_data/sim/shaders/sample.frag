#version 330
// Every step-th pixel of a drawn view, from the middle of the first step (numpy's
// `rgb[step // 2 :: step, step // 2 :: step]`): the pixels a camera's exposure meter reads.
// Uniforms: source (the drawn view's colour, texel for texel), step (drawn pixels between two
// samples along x and y), origin (the view's lower left pixel in the framebuffer written).
uniform sampler2D source;
uniform int step;
uniform ivec2 origin;
out vec4 colour;
void main() {
    ivec2 pixel = ivec2(gl_FragCoord.xy) - origin;  // in the view
    colour = texelFetch(source, pixel * step + step / 2, 0);
}
