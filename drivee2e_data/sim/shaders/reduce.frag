#version 330
// A view reduced by a whole factor: each pixel the mean of the factor x factor texels of the
// drawn view it covers, as an area resize by that factor averages them (OpenCV's INTER_AREA).
// Written to an 8-bit target, the mean is rounded to the nearest level; with an odd factor no
// mean lies halfway between two levels, so the bytes are those of the exact mean rounded.
// Uniforms: source (the drawn view's colour, texel for texel), factor (its pixels per output
// pixel along each axis).
uniform sampler2D source;
uniform int factor;
out vec4 colour;
void main() {
    ivec2 first = ivec2(gl_FragCoord.xy) * factor;
    vec4 total = vec4(0.0);
    for (int row = 0; row < factor; ++row) {
        for (int column = 0; column < factor; ++column) {
            total += texelFetch(source, first + ivec2(column, row), 0);
        }
    }
    colour = total / float(factor * factor);
}
