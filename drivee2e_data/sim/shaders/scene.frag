// The scene pass (common.glsl is prepended): materials, sun and shadow, sky light, street
// lamps and headlights, wet surfaces and fog; writes colour, body id and depth in one pass.
// Uniforms: sky_ambient, ground_ambient (light from above and below), shadow_map, fog_rgb,
// fog_density (per metre), wetness (0..1), camera_position, lamp_map (the street lamps'
// and the headlights' light on level ground, two channels of a raster), lamp_origin,
// lamp_extent (its world corner and size in metres), lamp_rgb, spot_rgb (the headlights'
// colour), wear_map, wear_origin, wear_extent (the road-wear raster: world corner, size in
// metres).
// Compiled in variants (the renderer prepends the defines that a clip's look needs: features
// a clip does not use cost nothing, where a uniform switch still cost a third of an image on
// llvmpipe): SHADOWS (the sun's shadow map), NIGHT (street lamps, headlights, lit windows),
// WET (darker, glossy ground), FOG (fog by depth). And per draw, the materials it holds:
// HAS_ASPHALT, HAS_MARKING, HAS_PAVEMENT, HAS_GRASS, HAS_FOLIAGE, HAS_FACADE, HAS_WINDOW (their
// textures' code), GLOSSY (highlights and reflections) and SUN_AVERTED (surfaces that face away
// from the sun: its term is zero there, so no shadow lookup); llvmpipe runs every branch for
// every pixel, so a draw pays only for the code its materials need.
#define LAMP_WALL_SHARE 0.35  // a wall gets this share of what level ground under it gets
#define BEAM_WALL_SHARE 1.0  // and of a headlight's (a beam meets it more squarely)
#define BEAM_HEIGHT_M 4.0  // headlights light surfaces below this
#define ASPHALT_GRAIN_PER_M 33.0  // the aggregate's noise cells a metre (3 cm; real chippings 0.6-2 cm)
#define MATTE 0
#define PAINT 1
#define GLASS 2
#define LAMP 3
#define ASPHALT 4
#define PAVEMENT 5
#define GRASS 6
#define FACADE 7
#define FOLIAGE 8
#define MARKING 9
#define TYRE 10
#define STREET_LAMP 11
#define WINDOW 12
#define WINDOW_LIT 13
#define FOLIAGE_FAR 14
#define WINDOW_GLASS vec3(0.12, 0.14, 0.17)  // a window by day, lit or not
uniform vec3 sky_ambient;
uniform vec3 ground_ambient;
uniform sampler2DShadow shadow_map;
uniform vec3 fog_rgb;
uniform float fog_density;
uniform float wetness;
uniform vec3 camera_position;
uniform sampler2D lamp_map;
uniform vec2 lamp_origin;
uniform vec2 lamp_extent;
uniform vec3 lamp_rgb;
uniform vec3 spot_rgb;
uniform sampler2D wear_map;
uniform vec2 wear_origin;
uniform vec2 wear_extent;
in vec3 world_position;
in vec3 normal;
in vec3 colour;
in float eye_depth;
in vec4 shadow_position;
flat in float body;
flat in float emission;
flat in int material;
layout(location = 0) out vec4 bgra;  // blue first: the JPEG encoder's order (gl_readback)
layout(location = 1) out float depth_out;
layout(location = 2) out float body_out;  // where the view reads ids

float sunlit() {
#if defined(SUN_AVERTED)
    return 0.0;
#elif !defined(SHADOWS)
    return 1.0;
#else
    vec3 p = shadow_position.xyz / shadow_position.w * 0.5 + 0.5;
    if (any(lessThan(p.xy, vec2(0.0))) || any(greaterThan(p.xy, vec2(1.0)))) return 1.0;
    // one tap of the hardware's 2x2 comparison filter (four taps cost 7% of an image here)
    float lit = texture(shadow_map, vec3(p.xy, p.z - 0.0006));
    // shadows fade out at the map's border instead of ending on a line
    vec2 edge = min(p.xy, 1.0 - p.xy);
    return mix(1.0, lit, smoothstep(0.0, 0.08, min(edge.x, edge.y)));
#endif
}

// how much of a procedural pattern a pixel can show when `cells_per_pixel` of its cells fall
// in one pixel: all of it up to half a cell, none from one cell on (finer detail would alias)
float resolved(float cells_per_pixel) {
    return clamp(2.0 - 2.0 * cells_per_pixel, 0.0, 1.0);
}

// the albedo of the procedural materials, and how shiny they are (x: specular share,
// y: exponent)
vec3 albedo(vec3 base, vec3 n, out vec2 shine, out float glow) {
    vec2 p = world_position.xy;
    float fine = clamp(1.0 - eye_depth / 35.0, 0.0, 1.0);  // grain fades before it aliases
    // the ground a pixel spans here, as the side of a square of its area (seen at a grazing
    // angle a pixel is long in depth and narrow across: its longer side had blurred the grain
    // out by 10 m); taken before any branch (derivatives need every pixel of a 2x2 block)
    float metres_per_pixel = sqrt(length(dFdx(p)) * length(dFdy(p)));
    shine = vec2(0.0, 1.0);
    glow = 0.0;
#ifdef HAS_ASPHALT
    if (material == ASPHALT) {
        // aggregate: smooth value noise in 3 cm cells (a hash per 11 cm cell had drawn flat
        // squares ten pixels wide 5-15 m ahead), faded out where its cells shrink towards a
        // pixel (as a mipmap would): the same grain at any image size
        float grain = (noise(p * ASPHALT_GRAIN_PER_M) - 0.5)
            * resolved(metres_per_pixel * ASPHALT_GRAIN_PER_M);
        vec2 ground = texture(wear_map, (p - wear_origin) / wear_extent).rg;  // wear, mottle
        return base * (1.0 + 0.4 * grain + 0.35 * (ground.g - 0.5)) * (1.0 - 0.28 * ground.r);
    }
#endif
#ifdef HAS_MARKING
    if (material == MARKING) {
        return base * (0.9 + 0.16 * noise(p * 4.0) * resolved(metres_per_pixel * 4.0));
    }
#endif
#ifdef HAS_PAVEMENT
    if (material == PAVEMENT) {
        vec2 slab = fract(p / vec2(0.6, 0.6));
        float joint = step(0.06, slab.x) * step(0.06, slab.y);
        float tone = 0.92 + 0.16 * hash(floor(p / 0.6));
        return base * tone * mix(0.8, 1.0, mix(1.0, joint, fine));
    }
#endif
#ifdef HAS_GRASS
    if (material == GRASS) {
        float mottle = texture(wear_map, (p - wear_origin) / wear_extent).g;
        float tufts = (noise(p * 9.0) - 0.5) * resolved(metres_per_pixel * 9.0);
        return base * (0.72 + 0.5 * mottle) * (1.0 + 0.3 * tufts);
    }
#endif
#ifdef HAS_FOLIAGE
    if (material == FOLIAGE || material == FOLIAGE_FAR) {
        vec2 q = world_position.xy * 2.2 + world_position.z * 1.7;
        return base * (0.6 + 0.7 * noise(q)) * (0.9 + 0.2 * hash(floor(q * 3.1)));
    }
#endif
#ifdef HAS_FACADE
    if (material == FACADE) {  // walls and roofs (the windows are quads of their own)
        if (abs(n.z) > 0.5) return base * 0.55;  // roofs: dark gravel
        float band = 1.0 - 0.12 * step(0.92, fract(world_position.z / 3.2));  // floor slabs
        // grime: a little darker towards the street
        return base * band * (0.9 + 0.1 * clamp(world_position.z / 6.0, 0.0, 1.0));
    }
#endif
#ifdef HAS_WINDOW
    if (material == WINDOW || material == WINDOW_LIT) {
        shine = vec2(0.5, 80.0);
#ifdef NIGHT
        if (material == WINDOW_LIT) {  // a lit room: its warm colour
            glow = 1.0;
            return base;
        }
#endif
        return WINDOW_GLASS;
    }
#endif
    if (material == PAINT) shine = vec2(0.35, 40.0);
    if (material == GLASS) shine = vec2(0.7, 120.0);
    if (material == TYRE) shine = vec2(0.02, 8.0);
    return base;
}

void main() {
    vec3 n = normalize(normal);
    if (!gl_FrontFacing) n = -n;  // thin parts of actors (drawn two-sided) seen from behind
    vec2 shine;
    float glow;
    vec3 base = albedo(colour, n, shine, glow);
#ifdef WET
    bool ground = material == ASPHALT || material == MARKING || material == PAVEMENT
        || material == GRASS;
    if (ground) {  // wet surfaces darken and turn glossy
        base *= 1.0 - 0.3 * wetness;
        shine = mix(shine, vec2(0.9, 60.0), wetness * (material == GRASS ? 0.2 : 1.0));
    }
#endif
    float sun = sunlit();
    vec3 ambient = mix(ground_ambient, sky_ambient, 0.5 + 0.5 * n.z);
    vec3 lit = base * (ambient + sun * sun_rgb * max(dot(n, light_direction), 0.0));
    float fresnel = 0.0;
#ifdef GLOSSY
    if (shine.x > 0.0) {  // glossy: paint, glass, lit windows, wet ground
        vec3 view = normalize(camera_position - world_position);
        vec3 half_vector = normalize(light_direction + view);
        lit += sun * shine.x * sun_rgb * pow(max(dot(n, half_vector), 0.0), shine.y);
        // the sky seen in glossy surfaces: Schlick's Fresnel term
        fresnel = 0.04 + 0.96 * pow(1.0 - max(dot(n, view), 0.0), 5.0);
        if (shine.x > 0.3) {
            vec3 reflected = reflect(-view, n);
            // the sky's gradient alone (its clouds in a reflection cost a tenth of an image)
            vec3 sky = mix(horizon_rgb, zenith_rgb, clamp(reflected.z, 0.0, 1.0));
            lit = mix(lit, sky * 0.8, clamp(fresnel * shine.x, 0.0, 0.85));
        }
    }
#endif
#ifdef NIGHT
    {  // street lamps (red) and headlights (green): their light on level ground, a raster
        vec2 level = texture(lamp_map, (world_position.xy - lamp_origin) / lamp_extent).rg;
        float up = max(n.z, 0.0);
        float facing = LAMP_WALL_SHARE + (1.0 - LAMP_WALL_SHARE) * up;
        float low = clamp(1.0 - world_position.z / 12.0, 0.2, 1.0);  // they shine down
        vec3 lamp = lamp_rgb * (level.r * facing * low);
        lit += base * lamp + lamp * (0.35 * shine.x * fresnel);  // a sheen on wet ground
        // headlights light low down
        float beam = level.g * mix(BEAM_WALL_SHARE, 1.0, up)
            * clamp(1.0 - world_position.z / BEAM_HEIGHT_M, 0.0, 1.0);
        lit += beam * spot_rgb * (base + 0.12 * shine.x);
    }
#endif
    float shining = emission;
#ifdef NIGHT
    if (material == STREET_LAMP) shining = 1.0;  // by day their faces have no emission
#endif
    lit = mix(lit, colour, clamp(shining, 0.0, 1.0));  // lamps shine their own colour
    lit = mix(lit, base, glow);
#ifdef FOG
    vec3 result = mix(fog_rgb, lit, exp(-fog_density * eye_depth));
#else
    vec3 result = lit;
#endif
    bgra = vec4(clamp(result, 0.0, 1.0).bgr, 1.0);
    body_out = body;
    depth_out = eye_depth;
}
