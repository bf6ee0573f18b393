#version 330
// A view exposed and reduced on the GPU as the CPU path does it (`conditions.expose`, then
// OpenCV's INTER_AREA): each drawn pixel's 8-bit levels times `gain`, rounded and saturated,
// then each output pixel the mean of the drawn pixels under its area, those it covers in part
// weighted by the part, rounded to the nearest level.
// Uniforms: source (the drawn view's colour, texel for texel), scale (drawn pixels per output
// pixel along x and y, 1 or more), gain (the camera's exposure; 1: as drawn), origin (the
// view's lower left pixel in the framebuffer written).
uniform sampler2D source;
uniform vec2 scale;
uniform float gain;
uniform ivec2 origin;
out vec4 colour;
void main() {
    // the output pixel's area, in the view's drawn pixels (whole numbers subtracted: exact)
    vec2 low = floor(gl_FragCoord.xy - vec2(origin)) * scale;
    vec2 high = low + scale;
    ivec2 first = ivec2(floor(low));
    ivec2 last = ivec2(ceil(high)) - 1;
    vec4 total = vec4(0.0);
    for (int row = first.y; row <= last.y; ++row) {
        float height = min(float(row + 1), high.y) - max(float(row), low.y);
        for (int column = first.x; column <= last.x; ++column) {
            float width = min(float(column + 1), high.x) - max(float(column), low.x);
            vec4 drawn = texelFetch(source, ivec2(column, row), 0);
            vec4 levels = min(roundEven(drawn * (255.0 * gain)), vec4(255.0));
            total += (width * height) * levels;
        }
    }
    // halves rounded up, as OpenCV's area resize by a whole factor rounds them
    colour = floor(total / (scale.x * scale.y) + 0.5) / 255.0;
}
