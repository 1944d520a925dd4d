"""Sky visibility, daylight and annual daylight: sky-patch visibility per face with adaptive
subdivision (Bosch, Besuievsky & Martin), relit for any sky, date, hour and place.

One package per technique: its processors, and the kernels, geometry and formats only it
uses. It imports core/, kernels/, geometry/ and formats/, never another technique."""
