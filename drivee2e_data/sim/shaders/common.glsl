// Shared by sky.frag and scene.frag (prepended to both): value noise and the sky's colour.
// Uniforms: light_direction, sun_rgb, zenith_rgb, horizon_rgb, cloud_cover, cloud_rgb,
// sun_disc (0 hides the sun: night, or under full cloud).
uniform vec3 light_direction;
uniform vec3 sun_rgb;
uniform vec3 zenith_rgb;
uniform vec3 horizon_rgb;
uniform float cloud_cover;
uniform vec3 cloud_rgb;
uniform float sun_disc;

float hash(vec2 p) {
    p = fract(p * vec2(0.1031, 0.1030));
    p += dot(p, p.yx + 33.33);
    return fract((p.x + p.y) * p.x);
}

float noise(vec2 p) {
    vec2 cell = floor(p);
    vec2 f = fract(p);
    vec2 u = f * f * (3.0 - 2.0 * f);
    return mix(mix(hash(cell), hash(cell + vec2(1.0, 0.0)), u.x),
               mix(hash(cell + vec2(0.0, 1.0)), hash(cell + vec2(1.0, 1.0)), u.x), u.y);
}

// two octaves: each more cost a twentieth of a camera image on llvmpipe (and a noise texture
// instead of hashes, twice the time there: filtered texture reads are dear on a CPU)
float fbm(vec2 p) {
    return 0.65 * noise(p) + 0.35 * noise(2.03 * p);
}

vec3 sky_colour(vec3 direction) {
    vec3 d = normalize(direction);
    float up = clamp(d.z, 0.0, 1.0);
    vec3 sky = mix(horizon_rgb, zenith_rgb, pow(up, 0.45));
    if (cloud_cover > 0.0 && d.z > 0.0) {
        vec2 plane = d.xy / max(d.z, 0.04) * 1.6;  // a cloud layer seen from below
        float density = fbm(plane + vec2(3.1, 7.7));
        float clouds = smoothstep(1.0 - cloud_cover, 1.15 - 0.5 * cloud_cover, density);
        clouds *= smoothstep(0.0, 0.12, d.z);  // thinning towards the horizon haze
        sky = mix(sky, cloud_rgb * (0.85 + 0.3 * density), clouds);
    }
    float towards_sun = max(dot(d, light_direction), 0.0);
    sky += sun_disc * sun_rgb * (0.25 * pow(towards_sun, 8.0) + 3.0 * pow(towards_sun, 900.0));
    return sky;
}
