#version 330
// A view reduced on the GPU as the CPU path does it (OpenCV's INTER_AREA): each output pixel
// the mean of the drawn pixels' 8-bit levels under its area, those it covers in part weighted
// by the part, rounded to the nearest level; at night the camera's noise made at its full size
// and averaged over the same area added, clipped and rounded (`conditions.with_reduced_noise`).
// Uniforms: source (the drawn view's colour, texel for texel), scale (drawn pixels per output
// pixel along x and y, 1 or more), origin (the view's lower left pixel in the framebuffer
// written), noise_start (the texel of noise_pool
// holding the view's first full-size pixel; -1: no noise), noise_pool (the pool's int8 levels
// three a texel from the view's phase on, `gl_reduce.NOISE_TEXTURE_WIDTH` texels a row),
// full_width (the camera's full width in pixels), noise_scale (full-size pixels per output
// pixel along x and y).
uniform sampler2D source;
uniform vec2 scale;
uniform ivec2 origin;
uniform int noise_start;
uniform isampler2D noise_pool;
uniform int full_width;
uniform vec2 noise_scale;
out vec4 colour;

const int NOISE_ROW_SHIFT = 12;  // 4096 texels a row of the pool's textures

// The mean of the noise under output pixel `pixel` (its column and row), RGB: each full-size
// pixel (one texel of the pool) weighted by the part of it the output pixel covers. The
// weights are multiples of a quarter where the scale is (TCP's 6.25, the camera policy's
// 12.5): the sums are then exact.
vec3 noise_mean(vec2 pixel) {
    vec2 low = pixel * noise_scale;
    vec2 high = low + noise_scale;
    ivec2 first = ivec2(floor(low));
    ivec2 last = ivec2(ceil(high)) - 1;
    int row_mask = (1 << NOISE_ROW_SHIFT) - 1;
    vec3 total = vec3(0.0);
    for (int row = first.y; row <= last.y; ++row) {
        float height = min(float(row + 1), high.y) - max(float(row), low.y);
        int texel = noise_start + row * full_width + first.x;
        vec3 row_total = vec3(0.0);
        for (int column = first.x; column <= last.x; ++column, ++texel) {
            float width = min(float(column + 1), high.x) - max(float(column), low.x);
            ivec2 at = ivec2(texel & row_mask, texel >> NOISE_ROW_SHIFT);
            row_total += width * vec3(texelFetch(noise_pool, at, 0).rgb);
        }
        total += height * row_total;
    }
    return total / (noise_scale.x * noise_scale.y);
}

void main() {
    // the output pixel's area, in the view's drawn pixels (whole numbers subtracted: exact)
    vec2 pixel = floor(gl_FragCoord.xy - vec2(origin));
    vec2 low = pixel * scale;
    vec2 high = low + scale;
    ivec2 first = ivec2(floor(low));
    ivec2 last = ivec2(ceil(high)) - 1;
    vec4 total = vec4(0.0);
    for (int row = first.y; row <= last.y; ++row) {
        float height = min(float(row + 1), high.y) - max(float(row), low.y);
        for (int column = first.x; column <= last.x; ++column) {
            float width = min(float(column + 1), high.x) - max(float(column), low.x);
            vec4 drawn = texelFetch(source, ivec2(column, row), 0);
            vec4 levels = roundEven(drawn * 255.0);
            total += (width * height) * levels;
        }
    }
    // halves rounded up, as OpenCV's area resize by a whole factor rounds them
    vec4 level = floor(total / (scale.x * scale.y) + 0.5);
    if (noise_start >= 0) {  // the colour is blue, green, red: the noise's channels backwards
        level.rgb = roundEven(clamp(level.rgb + noise_mean(pixel).bgr, 0.0, 255.0));
    }
    colour = level / 255.0;
}
